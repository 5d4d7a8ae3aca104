"""The study loop: NSGA-II by ask/tell, one batched evaluation per generation, a checkpoint after each.

:func:`run_study` validates everything first (study, output directory, lock, existing checkpoints,
engine), then for each controller of the study:

1. builds (or loads from the cache) the compiled run and evaluates the Table 2 gains on the study's
   draws (stored with the front, for comparison);
2. drives pymoo's NSGA-II with ``ask`` / ``tell``: each generation's offspring are evaluated in one
   batched call of the compiled run per draw (:class:`~arvcas.tuning.problem.GainProblem` through an
   engine);
3. after every generation writes ``front.h5`` atomically (population, ranks, crowding, counters and
   the generator state) and prints one progress line.

Resume is exact: NSGA-II's only source of randomness is ``algorithm.random_state`` (a NumPy
``Generator``, pymoo 0.6), whose ``bit_generator.state`` is stored as JSON; the population is restored
with its objectives, constraint, rank and crowding distance, and the counters. An uninterrupted run
and one stopped and resumed at any generation boundary produce the same generations bit for bit;
killing the process mid-generation loses only that generation.

SIGINT: the first Ctrl-C lets the current generation finish, writes its checkpoint and returns with
status ``interrupted`` and the command to resume; a second Ctrl-C aborts at once (the previous
checkpoint stays).
"""

from __future__ import annotations

import json
import math
import os
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.algorithms.moo.nsga3 import NSGA3
from pymoo.core.population import Population
from pymoo.core.termination import Termination
from pymoo.operators.crossover.sbx import SBX
from pymoo.operators.mutation.pm import PM
from pymoo.operators.sampling.rnd import FloatRandomSampling

from arvcas.build.provenance import model_hash
from arvcas.controllers.base import provenance
from arvcas.sim.scenario import held_dofs
from arvcas.sim.simulation import compiled_run
from arvcas.tuning import checkpoint as ck
from arvcas.tuning.engines import EngineError, EvalTask, make_engine
from arvcas.tuning.problem import Evaluation, GainProblem, assemble, assemble_objectives, pymoo_F
from arvcas.tuning.study import Study, StudyError

__all__ = ["TuningError", "Outcome", "StudyTermination", "hypervolume", "run_study", "front_path", "evaluate_gains"]


class TuningError(ValueError):
    """One-line error of a tuning run (resume mismatch, existing output)."""


@dataclass(frozen=True)
class Outcome:
    """How one controller's study ended."""

    controller: str
    path: Path
    status: str  # finished | interrupted
    stop_reason: str
    n_gen: int
    n_eval: int
    hv: float
    front_size: int
    wall_s: float  # this session


def hypervolume(F: np.ndarray, G: np.ndarray, ref) -> float:
    """Hypervolume of the feasible rows of F that dominate ``ref`` (pymoo's HV indicator); 0 if none."""
    from pymoo.indicators.hv import HV

    ref = np.asarray(ref, dtype=float)
    idx = ck.front_indices(F, G)
    P = F[idx] if idx.size else np.zeros((0, ref.size))
    P = P[np.all(P < ref, axis=1)]
    if P.shape[0] == 0:
        return 0.0
    return float(HV(ref_point=ref)(P))


class StudyTermination(Termination):
    """The study's stopping rule as one pymoo Termination (stop at the first criterion met).

    * ``max_generations`` (or ``max_generations_per_variable`` x n_var), ``max_evaluations``;
    * stall: over the last ``stall_generations`` generations the hypervolume of the feasible front
      (study reference point) grew by less than ``ftol`` relative to its current value.

    The hypervolume per generation is computed here, at pymoo's ``_post_advance``, and kept in
    :attr:`hv` (generation -> value); the study loop stores it, and restores it on resume.
    """

    def __init__(self, cfg, n_var: int, ref_point):
        super().__init__()
        self.max_gen = cfg.generations(n_var)
        self.max_evals = cfg.max_evaluations
        self.stall = cfg.stall_generations
        self.ftol = cfg.ftol
        self.ref = np.asarray(ref_point, dtype=float)
        self.hv: dict[int, float] = {}
        self.reason = ""

    def _update(self, algorithm) -> float:
        pop = algorithm.pop
        self.hv[int(algorithm.n_gen)] = hypervolume(pop.get("Fraw"), pop.get("G"), self.ref)
        return self.progress(int(algorithm.n_gen), int(algorithm.evaluator.n_eval))

    def progress(self, n_gen: int, n_eval: int) -> float:
        """Fraction done in [0, 1] (1: stop; :attr:`reason` says why)."""
        p, self.reason = 0.0, ""
        if self.max_gen is not None:
            p = max(p, n_gen / self.max_gen)
            if n_gen >= self.max_gen:
                self.reason = f"max_generations ({self.max_gen}) reached"
        if self.max_evals is not None:
            p = max(p, n_eval / self.max_evals)
            if n_eval >= self.max_evals and not self.reason:
                self.reason = f"max_evaluations ({self.max_evals}) reached"
        if self.stall is not None and not self.reason and n_gen > self.stall:
            now, then = self.hv.get(n_gen), self.hv.get(n_gen - self.stall)
            if now is not None and then is not None and now > 0 and (now - then) / now < self.ftol:
                self.reason = (f"stall: hypervolume grew by less than ftol = {self.ftol:g} (relative) "
                               f"over {self.stall} generations")
                p = 1.0
        self.perc = min(1.0, p) if not self.reason else 1.0
        return self.perc

    def generations_left(self, n_gen: int, n_eval: int, per_gen: int) -> int | None:
        left = []
        if self.max_gen is not None:
            left.append(max(0, self.max_gen - n_gen))
        if self.max_evals is not None:
            left.append(max(0, math.ceil((self.max_evals - n_eval) / max(1, per_gen))))
        return min(left) if left else None


class _Table2Sampling(FloatRandomSampling):
    """Uniform (log-uniform in gains) initial population whose first member is Table 2."""

    def __init__(self, x0):
        super().__init__()
        self.x0 = np.asarray(x0, dtype=float)

    def _do(self, problem, n_samples, *args, random_state=None, **kwargs):
        X = super()._do(problem, n_samples, *args, random_state=random_state, **kwargs)
        X[0] = self.x0
        return X


def front_path(out: Path, study: Study, controller: str) -> Path:
    """``OUT/front.h5`` for a one-controller study, ``OUT/<controller>/front.h5`` otherwise."""
    return out / ck.FRONT_NAME if len(study.controllers) == 1 else out / controller / ck.FRONT_NAME


def reference_directions(study: Study) -> np.ndarray:
    """NSGA-III's reference directions (pymoo): Das-Dennis on the unit simplex with ``partitions`` (default:
    the most partitions whose point count does not exceed the population), or ``energy`` (Riesz s-energy,
    as many as the population, seeded by the study's seed)."""
    from math import comb

    from pymoo.util.ref_dirs import get_reference_directions

    a, m = study.algorithm, len(study.objectives.names)
    if a.ref_dirs == "energy":
        return get_reference_directions("energy", m, a.population, seed=study.seed)
    p = a.partitions
    if p is None:
        p = 1
        while comb(p + 1 + m - 1, m - 1) <= a.population:
            p += 1
    return get_reference_directions("das-dennis", m, n_partitions=p)


def _comp_by_cv_then_random(pop, P, random_state=None, **kwargs):
    """pymoo 0.6.2's NSGA-III tournament (``nsga3.comp_by_cv_then_random``: the smaller constraint violation
    wins; between feasible ones a random pick) with the algorithm's generator also for a tie of violations:
    pymoo's own calls ``compare(..., return_random_if_equal=True)`` without it, so such a tie draws from a
    fresh unseeded generator and a study with constraints would not repeat (nor resume) bit for bit."""
    from pymoo.algorithms.moo.nsga3 import compare

    S = np.full(P.shape[0], np.nan)
    for i in range(P.shape[0]):
        a, b = P[i, 0], P[i, 1]
        if pop[a].CV > 0.0 or pop[b].CV > 0.0:
            S[i] = compare(a, pop[a].CV, b, pop[b].CV, method="smaller_is_better", return_random_if_equal=True,
                           random_state=random_state)
        else:
            S[i] = random_state.choice([a, b])
    return S[:, None].astype(int)


def make_algorithm(study: Study, controller: str):
    a = study.algorithm
    _, _, _, g0 = study.bounds(controller)
    sampling = _Table2Sampling(np.log10(g0)) if a.include_table2 else FloatRandomSampling()
    if a.name == "nsga3":
        dirs = reference_directions(study)
        if dirs.shape[0] > a.population:
            raise StudyError(f"{study.path}: algorithm.population: {a.population} is below the {dirs.shape[0]} reference "
                             f"directions of NSGA-III (give population >= {dirs.shape[0]} or fewer partitions)")
        from pymoo.operators.selection.tournament import TournamentSelection

        return NSGA3(ref_dirs=dirs, pop_size=a.population, n_offsprings=a.n_offspring, sampling=sampling,
                     selection=TournamentSelection(func_comp=_comp_by_cv_then_random),
                     crossover=SBX(prob=a.crossover_prob, eta=a.crossover_eta),
                     mutation=PM(eta=a.mutation_eta, prob_var=a.mutation_prob_var),
                     eliminate_duplicates=a.eliminate_duplicates, seed=study.seed, output=None)
    return NSGA2(
        pop_size=a.population, n_offsprings=a.n_offspring, sampling=sampling,
        crossover=SBX(prob=a.crossover_prob, eta=a.crossover_eta),
        mutation=PM(eta=a.mutation_eta, prob_var=a.mutation_prob_var),
        eliminate_duplicates=a.eliminate_duplicates, seed=study.seed, output=None,
    )


def eval_task(study: Study, controller: str, params=None) -> EvalTask:
    cfg = study.scenario
    draws = tuple((d.noise_seed, *d.resolved(cfg)) for d in study.draws)
    params = params if params is not None else study.system_params()
    src = provenance(controller)
    ship = (src["spec"],) if src.get("kind") in ("file", "module") else ()  # an entry point is found by itself
    accs = study.objectives.accumulators()
    if not study.objectives.default:
        from arvcas.metrics import objectives as objectives_mod

        objs, cons = study.objectives.objects()
        for o in list(objs) + [o for o, _ in cons]:
            src = objectives_mod.origin(o.name)
            if src.get("kind") in ("file", "module") and src["spec"] not in ship:
                ship += (src["spec"],)
    ref, norm = normalisation(study, params, draws)
    return EvalTask(controller=controller, draws=draws, cfg=cfg, params=params, ref=ref, plugins=ship,
                    chat=study.objectives.chat, accumulators=accs, normalisation=norm)


def normalisation(study: Study, params, draws) -> tuple[tuple | None, str]:
    """The objectives' per-DOF normalisation and where it comes from (docs/objectives.md, "Normalisation"):
    ``(None, "the paper's AGSTA value")`` (Table 3) for Haidou-1 (named in the study or the default) unless
    the study gives its own values; else the
    values the study gives (``objectives.normalisation_chat``, ``normalisation_rmse``), or a law at its
    default gains on the study's first draw: the one ``objectives.normalisation`` names, or with "auto"
    the first of the AGSTA and the study's own controllers whose defaults run to the end on that draw (the
    AGSTA first: the system's own AGSTA scores (1, 1), docs/model.md §7). A law without defaults, or whose
    defaults diverge, is passed over; none left is one line."""
    o = study.objectives
    if o.normalisation_chat is not None:
        return (tuple(o.normalisation_chat), tuple(o.normalisation_rmse)), \
            "the study's objectives.normalisation_chat and normalisation_rmse"
    if not _system_ref(study) and o.normalisation == "auto":
        return None, "the paper's AGSTA value"
    from arvcas.controllers.base import ControllerError
    from arvcas.sim.simulation import compiled_run

    laws = list(dict.fromkeys(["agsta", *study.controllers])) if o.normalisation == "auto" else [o.normalisation]
    seed, unc, ph = draws[0]
    tried = []
    for law in laws:
        try:
            run = compiled_run(law, params, study.scenario)
            gains = run.default_gains()
        except ControllerError as e:
            if o.normalisation != "auto":
                raise StudyError(f"{study.path}: objectives.normalisation: {e}") from None
            tried.append(f"{law} has no default gains")
            continue
        chat, rmse, ok, t_fail = run.many(gains, [seed], uncertainty=unc, phase=ph, n_threads=1, chat=o.chat)
        if ok[0]:
            return (tuple(chat[0].tolist()), tuple(rmse[0].tolist())), \
                f"{law}'s value at the default gains of {params.structure.name} on draw 1"
        tried.append(f"{law} at its default gains diverges at {t_fail[0]:.3g} s")
    raise StudyError(f"{study.path}: objectives.normalisation: no normalisation for the objectives on draw 1 of "
                     f"{params.structure.name} ({'; '.join(tried)}): give objectives.normalisation_chat and "
                     f"normalisation_rmse (six values each), or name a law whose defaults run")


def evaluate_gains(engine, task: EvalTask, gains: np.ndarray, objectives=None) -> Evaluation:
    """One batched evaluation of gain sets (n, n_var) through ``engine``: objectives and constraint.
    ``objectives``: the study's :meth:`ObjectivesConfig.objects` when they are not the paper's (the task then
    carries their accumulators)."""
    G = np.atleast_2d(np.asarray(gains, dtype=float))
    if task.accumulators:
        from arvcas.metrics import objectives as objectives_mod

        objs, cons = objectives
        ctx = objectives_mod.Context(cfg=task.cfg, params=task.params, ref=task.ref, chat="chat",
                                     slices=objectives_mod.slices(task.accumulators, task.params.structure.n_thrusters,
                                                                  task.cfg))
        return assemble_objectives(engine.evaluate(task, G), objs, cons, ctx, task.cfg.time_duration)
    chat, rmse, ok, t_fail = engine.evaluate(task, G)
    return assemble(chat, rmse, ok, t_fail, task.cfg.time_duration, task.ref, held_dofs(task.cfg))


# ---- interruption --------------------------------------------------------------------------------


class _Stop:
    """SIGINT once: finish the generation, checkpoint, return; twice: KeyboardInterrupt."""

    def __init__(self):
        self.requested = False
        self._old = None

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handler)
        return self

    def _handler(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        # os.write: print() is not reentrant and the main thread may be printing
        os.write(2, b"interrupt: stopping after this generation (Ctrl-C again to abort now; "
                    b"the last checkpoint is kept)\n")

    def __exit__(self, *exc):
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)


# ---- the loop ------------------------------------------------------------------------------------------


def _fmt_s(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def _new_checkpoint(study: Study, controller: str, task: EvalTask) -> ck.Checkpoint:
    names, lo, hi, g0 = study.bounds(controller)
    return ck.Checkpoint(
        controller=controller, study_name=study.name, study_text=study.text, study_path=study.path,
        identity=study.identity_json(controller), scenario_text=study.scenario.text, seed=study.seed,
        names=names, lower=lo, upper=hi, table2=g0,
        draw_seeds=np.array([d[0] for d in task.draws], dtype=np.int64),
        draw_uncertainty=np.array([d[1] for d in task.draws]), draw_phase=np.array([d[2] for d in task.draws]),
        params=task.params.vector(), reference_point=np.asarray(study.objectives.reference_point, dtype=float),
        versions=ck.versions(), model_hash=model_hash(), system=_system_ref(study),
        ref_chat=None if task.ref is None else np.asarray(task.ref[0]),
        ref_rmse=None if task.ref is None else np.asarray(task.ref[1]), plugin=provenance(controller),
        normalisation=task.normalisation,
    )


def _system_ref(study: Study) -> str:
    """How a checkpoint names the study's system (:func:`arvcas.system.result_ref`: "" for the default system,
    named or not; the front file stores a file's path relative to its own folder: :mod:`arvcas.tuning.checkpoint`)."""
    from arvcas.system import result_ref

    return result_ref(study.params)


def _identity_diff(stored: str, current: dict) -> list[str]:
    old = json.loads(stored)
    return sorted(k for k in set(old) | set(current) if old.get(k) != json.loads(json.dumps(current.get(k))))


def _pop_arrays(pop) -> dict:
    return {
        "X": pop.get("X"), "F": pop.get("Fraw"), "G": pop.get("G"),
        "rank": _float(pop.get("rank")), "crowding": _float(pop.get("crowding")),
        "chat": np.transpose(np.stack(pop.get("chat_k")), (1, 0, 2)),
        "rmse": np.transpose(np.stack(pop.get("rmse_k")), (1, 0, 2)),
        "ok": np.stack(pop.get("ok_k")).T, "t_fail": np.stack(pop.get("t_fail_k")).T,
    }


def _float(a) -> np.ndarray:
    return np.array([np.nan if v is None else float(v) for v in a], dtype=float)


def _set_eval(pop, ev: Evaluation) -> None:
    pop.set("Fraw", ev.F, "chat_k", np.transpose(ev.chat, (1, 0, 2)), "rmse_k", np.transpose(ev.rmse, (1, 0, 2)),
            "ok_k", ev.ok.T, "t_fail_k", ev.t_fail.T)


def _restore(alg: NSGA2, term: StudyTermination, c: ck.Checkpoint) -> None:
    """Put a fresh, set-up NSGA-II into the state it had after generation ``c.n_gen``."""
    # survival leaves rank and crowding unset (None, stored as NaN) on some infeasible members
    rank = [None if np.isnan(r) else int(r) for r in c.rank]
    crowd = [None if np.isnan(x) else float(x) for x in c.crowding]
    pop = Population.new("X", c.X, "F", pymoo_F(c.F, c.G), "G", c.G, "H", np.zeros((c.X.shape[0], 0)))
    pop.set("rank", rank, "crowding", crowd)
    pop.set("Fraw", c.F, "chat_k", np.transpose(c.chat, (1, 0, 2)), "rmse_k", np.transpose(c.rmse, (1, 0, 2)),
            "ok_k", c.ok.T, "t_fail_k", c.t_fail.T)
    for ind in pop:
        ind.evaluated.update({"F", "G", "H"})
    alg.start_time = time.time()
    alg.pop = pop
    alg.off = None
    alg.opt = None
    alg.is_initialized = True
    alg.n_iter = c.n_gen + 1  # pymoo increments after each tell
    alg.evaluator.n_eval = c.n_eval
    alg.random_state.bit_generator.state = json.loads(c.rng_state)
    if isinstance(alg, NSGA3) and c.survival:  # the hyperplane normalisation NSGA-III carries between generations
        st, norm = json.loads(c.survival), alg.survival.norm
        norm.ideal_point, norm.worst_point = np.array(st["ideal"], dtype=float), np.array(st["worst"], dtype=float)
        norm.extreme_points = None if st["extreme"] is None else np.array(st["extreme"], dtype=float)
        alg.survival.opt = pop[[i for i, r in enumerate(rank) if r == 0 and (c.G[i] <= 0).all()]]  # the result only
    alg._set_optimum()
    term.hv = {int(g): float(h) for g, h in zip(c.history["gen"], c.history["hv"])}
    term.progress(c.n_gen, c.n_eval)


def _survival_json(alg) -> str:
    """NSGA-III's normalisation state (ideal, worst and extreme points) as JSON ("" for NSGA-II)."""
    if not isinstance(alg, NSGA3):
        return ""
    n = alg.survival.norm
    ext = None if n.extreme_points is None else np.asarray(n.extreme_points).tolist()
    return json.dumps({"ideal": np.asarray(n.ideal_point).tolist(), "worst": np.asarray(n.worst_point).tolist(),
                       "extreme": ext})


def _rng_json(alg: NSGA2) -> str:
    st = alg.random_state.bit_generator.state

    def conv(o):
        if isinstance(o, dict):
            return {k: conv(v) for k, v in o.items()}
        if isinstance(o, np.integer):
            return int(o)
        if isinstance(o, np.ndarray):
            return o.tolist()
        return o

    return json.dumps(conv(st), sort_keys=True)


def run_study(study: Study, out: str | Path, *, controllers: tuple[str, ...] | None = None, resume: bool = False,
              say: Callable[[str], None] = print, stop_after: int | None = None, study_file: str | None = None,
              params=None, allow_model_change: bool = False) -> list[Outcome]:
    """Run (or resume) the study's controllers into ``out``; returns one :class:`Outcome` each.

    All checks happen before any simulation: output directory (created if its parent exists),
    the lock, existing checkpoints (refused without ``resume``; validated and compared with the
    study with it), the engine (a Dask scheduler must answer within the study's timeout).
    ``stop_after`` stops after that many generations in total as if interrupted (tests).
    A checkpoint computed with other model code, data or parameters (:func:`ck.provenance_diff`) is
    refused on resume unless ``allow_model_change``; then the checkpoint records it in ``model_changes``
    and continues under this installation's model.
    """
    out = ck.check_out_dir(Path(out))
    ctrls = study.controllers if controllers is None else tuple(controllers)
    for c in ctrls:
        if c not in study.controllers:
            raise StudyError(f"--controller {c}: not in the study's controllers ({', '.join(study.controllers)})")
    study_file = study_file or study.path
    resume_cmd = f"arvcas tune {study_file} --out {out} --resume"
    outcomes: list[Outcome] = []
    with ck.StudyLock(out):
        plan = []
        for c in ctrls:
            path = front_path(out, study, c)
            if path.parent != out:
                ck.check_out_dir(path.parent, "--out")
            ck.remove_stale_temps(path.parent)
            existing = None
            if path.exists():
                if not resume:
                    raise TuningError(f"{path}: a study checkpoint exists; continue it with --resume or choose another --out")
                existing = ck.read_checkpoint(path)
                if existing.controller != c:
                    raise TuningError(f"{path}: holds controller '{existing.controller}', not '{c}'")
                diff = _identity_diff(existing.identity, study.identity(c))
                if diff:
                    raise TuningError(f"--resume: {study.path} differs from the study in {path} in {', '.join(diff)} "
                                      f"(only [termination] and [engine] may change between sessions)")
                changed = ck.provenance_diff(existing, params if params is not None else study.system_params(),
                                             str(path))
                if changed and not allow_model_change:
                    raise TuningError(f"--resume {path}: {'; '.join(changed)}; continuing would mix two models in "
                                      f"one front (--allow-model-change to continue anyway; the checkpoint records it)")
                if changed:
                    existing.model_changes = list(existing.model_changes) + [
                        f"{ck._now()}: resumed at generation {existing.n_gen} with --allow-model-change: "
                        + "; ".join(changed)]
                    existing.model_hash = model_hash()
                    existing.run_digest = ""  # set by the session below, from the run it compiles
                    existing.plugin = provenance(c)
                    existing.params = (params if params is not None else study.system_params()).vector()
            elif resume:
                say(f"{c}: no checkpoint at {path}: starting the study")
            plan.append((c, path, existing))
        if all(e is not None and e.status == "finished" and not _extends(study, e) for _, _, e in plan):
            for c, path, e in plan:
                say(f"{c}: already finished ({e.stop_reason}) in {path}")
                outcomes.append(_outcome(e, path, 0.0))
            return outcomes
        engine = make_engine(study.engine)
        try:
            with _Stop() as stop:
                for c, path, existing in plan:
                    o = _run_one(study, c, path, existing, engine, stop, say, stop_after, resume_cmd, params)
                    outcomes.append(o)
                    if o.status != "finished":
                        break
        finally:
            engine.close()
    return outcomes


def _extends(study: Study, c: ck.Checkpoint) -> bool:
    """A finished checkpoint that the (changed) termination of ``study`` would continue."""
    term = StudyTermination(study.termination, len(c.names), c.reference_point)
    term.hv = {int(g): float(h) for g, h in zip(c.history["gen"], c.history["hv"])}
    return term.progress(c.n_gen, c.n_eval) < 1.0


def _outcome(c: ck.Checkpoint, path: Path, wall: float) -> Outcome:
    hv = float(c.history["hv"][-1]) if c.n_gen else 0.0
    return Outcome(controller=c.controller, path=path, status=c.status, stop_reason=c.stop_reason, n_gen=c.n_gen,
                   n_eval=c.n_eval, hv=hv, front_size=int(c.front.size) if c.X is not None else 0, wall_s=wall)


def _run_one(study: Study, controller: str, path: Path, c: ck.Checkpoint | None, engine, stop: _Stop, say,
             stop_after: int | None, resume_cmd: str, params) -> Outcome:
    t_session = time.time()
    names, lo, hi, g0 = study.bounds(controller)
    task = eval_task(study, controller, params)
    say(f"{controller}: {len(names)} gains, population {study.algorithm.population}, engine {engine.describe()}; "
        f"preparing the compiled run ...")
    say(f"{controller}: objectives normalised by {task.normalisation}")
    key = engine.prepare(task)
    digest = compiled_run(task.controller, task.params, task.cfg, accumulators=task.accumulators).digest()
    objs = study.objectives.objects() if task.accumulators else None
    n_constr = 1 + len(study.objectives.constraints)
    problem = GainProblem(names, np.log10(lo), np.log10(hi), lambda G: evaluate_gains(engine, task, G, objs),
                          n_obj=len(study.objectives.names), n_constr=n_constr)
    alg = make_algorithm(study, controller)
    term = StudyTermination(study.termination, len(names), study.objectives.reference_point)
    alg.setup(problem, termination=term, verbose=False)

    if c is None:
        c = _new_checkpoint(study, controller, task)
        c.artifact_key, c.run_digest, c.engine = key, digest, engine.describe()
        t2 = evaluate_gains(engine, task, g0[None, :], objs)
        c.table2_F, c.table2_G = t2.F[0], t2.G[0]
        c.table2_chat, c.table2_rmse = t2.chat[:, 0], t2.rmse[:, 0]
        c.table2_ok, c.table2_t_fail = t2.ok[:, 0], t2.t_fail[:, 0]
        ck.write_checkpoint(c, path)
        t2txt = (", ".join(f"f_{n} {v:.4g}" for n, v in zip(study.objectives.names, t2.F[0])) if t2.G[0, 0] <= 0
                 else "infeasible (diverged)")
        which = "Table 2 gains" if study.system is None else f"default gains of {task.params.structure.name}"
        say(f"{controller}: {which} on the study's draws: {t2txt}")
    else:
        if c.n_gen > 0:
            _restore(alg, term, c)
        if c.run_digest and c.run_digest != digest:
            say(f"{controller}: warning: the compiled run differs from the checkpoint's (run digest "
                f"{digest[:12]} vs {c.run_digest[:12]}): the continued study is not bit-identical to an "
                f"uninterrupted one")
        c.artifact_key, c.run_digest, c.engine = key, digest, engine.describe()
        say(f"{controller}: resuming {path} after generation {c.n_gen} ({c.n_eval} evaluations)")

    hist = {k: list(np.asarray(c.history[k], dtype=float)) for k in ck.HISTORY_FIELDS}
    elapsed0 = hist["elapsed_s"][-1] if hist["elapsed_s"] else 0.0
    gen_times: list[float] = []
    per_gen = study.algorithm.n_offspring
    max_gen = term.max_gen
    if c.n_gen > 0 and term.perc >= 1.0:
        c.status, c.stop_reason = "finished", term.reason
        ck.write_checkpoint(c, path)
        say(f"{controller}: already finished ({term.reason})")
        return _outcome(c, path, time.time() - t_session)

    while True:
        t0 = time.time()
        off = alg.ask()
        try:
            alg.evaluator.eval(problem, off)
        except EngineError as e:
            if not stop.requested:
                raise EngineError(f"{e}; the checkpoint of generation {c.n_gen} is kept in {path}; "
                                  f"resume with: {resume_cmd}") from None
            # Ctrl-C reached the workers too (same process group): this generation is lost, the last is kept
            c.status, c.stop_reason = "interrupted", "interrupted"
            ck.write_checkpoint(c, path)
            say(f"{controller}: interrupted during generation {c.n_gen + 1} ({e}); checkpoint of generation "
                f"{c.n_gen} kept in {path}; resume with: {resume_cmd}")
            return _outcome(c, path, time.time() - t_session)
        _set_eval(off, problem.last)
        alg.tell(infills=off)
        n_gen, n_eval = int(alg.n_iter - 1), int(alg.evaluator.n_eval)
        dt = time.time() - t0
        gen_times.append(dt)

        arrays = _pop_arrays(alg.pop)
        for k, v in arrays.items():
            setattr(c, k, v)
        c.gains = np.power(10.0, c.X)
        feas = (c.G <= 0).all(axis=1)
        hv = term.hv[n_gen]
        best = np.nanmin(c.F[feas], axis=0) if feas.any() else np.full(c.F.shape[1], np.nan)
        row = {"gen": n_gen, "n_eval": n_eval, "n_feasible": int(feas.sum()), "hv": hv, "best_chat": best[0],
               "best_rmse": best[1], "gen_time_s": dt, "elapsed_s": elapsed0 + time.time() - t_session}
        for k in ck.HISTORY_FIELDS:
            hist[k].append(float(row[k]))
        c.history = {k: np.array(v) for k, v in hist.items()}
        c.n_gen, c.n_eval, c.rng_state = n_gen, n_eval, _rng_json(alg)
        c.survival = _survival_json(alg)
        done = term.perc >= 1.0
        halted = stop.requested or (stop_after is not None and n_gen >= stop_after)
        c.status = "finished" if done else ("interrupted" if halted else "running")
        c.stop_reason = term.reason if done else ("interrupted" if halted else "")
        ck.write_checkpoint(c, path)

        left = term.generations_left(n_gen, n_eval, per_gen)
        mean_t = float(np.mean(gen_times[-10:]))
        eta = f"  left ~{_fmt_s(left * mean_t)}" if left else ""
        of = f"/{max_gen}" if max_gen is not None else ""
        bc = f"{best[0]:.4g}" if np.isfinite(best[0]) else "-"
        br = f"{best[1]:.4g}" if np.isfinite(best[1]) else "-"
        if study.objectives.names == ("chat", "rmse"):
            bests = f"best CHAT {bc}  best RMSE {br}"
        else:  # the smallest value of each objective in the population
            bests = "  ".join(f"best {n} {b:.4g}" if np.isfinite(b) else f"best {n} -"
                              for n, b in zip(study.objectives.names, best))
        say(f"{controller} gen {n_gen}{of}  evals {n_eval}  feasible {int(feas.sum())}/{len(feas)}  "
            f"HV {hv:.5g}  {bests}  {dt:.1f} s/gen{eta}")
        if done:
            say(f"{controller}: finished: {term.reason}; {c.front.size} on the front; {path}")
            return _outcome(c, path, time.time() - t_session)
        if halted:
            say(f"{controller}: stopped after generation {n_gen}; checkpoint {path}; resume with: {resume_cmd}")
            return _outcome(c, path, time.time() - t_session)
