"""Fronts as data: :class:`Front` (read from ``front.h5``), export, plot, knee point, replay.

Front members are the feasible, non-dominated rows of the study's final (or latest) population,
sorted by ``f_chat``; member ``i`` of every function here is row ``i`` of that order.

Knee point: pymoo's :class:`~pymoo.mcdm.pseudo_weights.PseudoWeights` with equal weights (0.5, 0.5; for m
objectives 1/m each, docs/objectives.md): the member whose pseudo-weight vector
``w_i ~ (f_i,max - f_i) / (f_i,max - f_i,min)`` (normalised to sum 1; Deb, *Multi-Objective Optimization
using Evolutionary Algorithms*, Wiley 2001, the pseudo-weight vector approach) is closest to equal weights,
i.e. the balanced compromise where every objective is the same fraction of the way from its worst to its
best value on the front. Always exactly one member,
and insensitive to the scale of either objective. pymoo's ``HighTradeoffPoints`` was tried first and
rejected: on these fronts (noisy at the scale of neighbouring members) its local trade-off ratios
pick an end of the front (a nearly vertical step between two neighbours), not the bend.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arvcas.metrics import DOFS, table3
from arvcas.tuning import checkpoint as ck

__all__ = ["Front", "read_front", "knee_index", "export_front", "plot_front", "plot_fronts", "member_gains",
           "member_index", "replay", "replay_all", "restamp", "Replayed", "resolve_front_path", "front_paths",
           "check_provenance", "check_same_model", "system_params"]


def resolve_front_path(p: str | Path) -> Path:
    """A ``front.h5`` path from a file or a study output directory (one controller)."""
    p = Path(p)
    if p.is_dir():
        f = p / ck.FRONT_NAME
        if f.exists():
            return f
        subs = sorted(q for q in p.glob(f"*/{ck.FRONT_NAME}"))
        if subs:
            raise ck.CheckpointError(f"{p}: holds several fronts ({', '.join(str(s.parent.name) for s in subs)}); "
                                     f"give one of {', '.join(str(s) for s in subs)}")
        raise ck.CheckpointError(f"{p}: no {ck.FRONT_NAME} in this directory")
    return p


def front_paths(p: str | Path) -> list[Path]:
    """Every ``front.h5`` of a study output directory (sorted by controller directory): the
    ``<controller>/front.h5`` of a study of several controllers, or the ``front.h5`` of a study of one
    (the directory itself, or that file)."""
    p = Path(p)
    if not p.is_dir():
        return [p]
    fronts = sorted(p.glob(f"*/{ck.FRONT_NAME}"))
    if not fronts and (p / ck.FRONT_NAME).is_file():
        return [p / ck.FRONT_NAME]
    if not fronts:
        raise ck.CheckpointError(f"{p}: no {ck.FRONT_NAME} and no <controller>/{ck.FRONT_NAME} in this directory "
                                 "(the --out of arvcas tune)")
    return fronts


@dataclass(frozen=True)
class Front:
    """A study's front and its provenance. Arrays over the f front members, sorted by f_chat.

    ``F`` (f, 2) = (f_chat, f_rmse), docs/model.md §7 (paper's AGSTA = (1, 1)); ``gains`` (f, m) with
    ``names``; ``index`` (f,) rows in the stored population; ``chat``/``rmse`` (K, f, 6) per draw
    and DOF; ``table2_F`` (2,) Table 2 on the same draws (NaN if it diverged).
    """

    path: Path
    controller: str
    study_name: str
    status: str
    n_gen: int
    n_eval: int
    names: list
    gains: np.ndarray
    X: np.ndarray
    F: np.ndarray
    G: np.ndarray
    index: np.ndarray
    chat: np.ndarray
    rmse: np.ndarray
    population_F: np.ndarray
    population_G: np.ndarray
    table2: np.ndarray
    table2_F: np.ndarray
    table2_G: np.ndarray
    reference_point: np.ndarray
    history: dict
    seed: int
    draw_seeds: np.ndarray
    draw_uncertainty: np.ndarray
    draw_phase: np.ndarray
    scenario_text: str
    study_text: str
    versions: dict
    system: str = ""  # the study's system ("": Haidou-1, objectives normalised by the paper's Table 3)
    plugin: dict | None = None  # a controller from outside the package: where it came from (checkpoint.py)
    objectives: tuple = ("chat", "rmse")  # the study's objectives, the columns of F (docs/objectives.md)
    normalisation: str = ""  # where f_chat and f_rmse's reference comes from, in words ("": not recorded)

    @property
    def size(self) -> int:
        return int(self.F.shape[0])

    @property
    def labels(self) -> list[str]:
        """The columns of F: ``f_chat``, ``f_rmse``, ``f_<objective>``."""
        return [f"f_{n}" for n in self.objectives]

    def describe(self, i: int, fmt: str = ".4g") -> str:
        """Member ``i``'s objectives: ``"f_chat 1.2, f_rmse 3.4"``."""
        return ", ".join(f"{lab} {v:{fmt}}" for lab, v in zip(self.labels, self.F[i]))

    @property
    def hv(self) -> float:
        """Hypervolume of the front against the study's reference point."""
        from arvcas.tuning.run import hypervolume

        return hypervolume(self.F, self.G, self.reference_point)

    def knee(self) -> int:
        """Index (into the front) of the knee point; see the module docstring."""
        return knee_index(self.F)

    def plot(self, ax=None, **kw):
        return plot_front(self, ax=ax, **kw)


def read_front(path: str | Path) -> Front:
    """Read ``front.h5`` (or a study directory holding one); one-line error if it is not one."""
    path = resolve_front_path(path)
    c = ck.read_checkpoint(path)
    if c.X is None:
        raise ck.CheckpointError(f"{path}: no generation finished yet (nothing on the front); "
                                 f"resume the study to continue")
    idx = c.front
    nan2 = np.full(2, np.nan)
    return Front(
        path=path, controller=c.controller, study_name=c.study_name, status=c.status, n_gen=c.n_gen,
        n_eval=c.n_eval, names=list(c.names), gains=c.gains[idx], X=c.X[idx], F=c.F[idx], G=c.G[idx], index=idx,
        chat=c.chat[:, idx], rmse=c.rmse[:, idx], population_F=c.F, population_G=c.G, table2=c.table2,
        table2_F=c.table2_F if c.table2_F is not None else nan2,
        table2_G=c.table2_G if c.table2_G is not None else np.full(1, np.nan),
        reference_point=c.reference_point, history=c.history, seed=c.seed, draw_seeds=c.draw_seeds,
        draw_uncertainty=c.draw_uncertainty, draw_phase=c.draw_phase, scenario_text=c.scenario_text,
        study_text=c.study_text, versions=c.versions, system=c.system, plugin=c.plugin or None,
        objectives=objective_names(c), normalisation=c.normalisation,
    )


def objective_names(c: ck.Checkpoint) -> tuple:
    """The objectives of a checkpoint's study (its identity's ``objectives.names``)."""
    try:
        names = json.loads(c.identity)["objectives"]["names"]
    except (ValueError, KeyError, TypeError):
        names = None
    if not (isinstance(names, list) and len(names) == c.reference_point.size):
        return ("chat", "rmse")[:c.reference_point.size]
    return tuple(str(n) for n in names)


def knee_index(F: np.ndarray) -> int:
    """Knee of an m-objective front: pymoo's PseudoWeights(1/m, ..., 1/m); see the module docstring."""
    from pymoo.mcdm.pseudo_weights import PseudoWeights

    F = np.asarray(F, dtype=float)
    n = F.shape[0]
    if n == 0:
        raise ValueError("knee: the front is empty")
    if n == 1:
        return 0
    if np.any(F.max(axis=0) == F.min(axis=0)):  # a degenerate front: pseudo-weights undefined
        return int(np.argmin(_normalise(F).sum(axis=1)))
    return int(PseudoWeights(np.full(F.shape[1], 1.0 / F.shape[1]) if F.shape[1] != 2 else np.array([0.5, 0.5])).do(F))


def _normalise(F: np.ndarray) -> np.ndarray:
    lo, hi = F.min(axis=0), F.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    return (F - lo) / span


# ---- export ---------------------------------------------------------------------------------------


def _records(fr: Front) -> tuple[list[str], list[list]]:
    knee = fr.knee() if fr.size else -1
    head = ["member", "population_row", *fr.labels, "G", "knee"] + list(fr.names) \
        + [f"chat.{d}" for d in DOFS] + [f"rmse.{d}" for d in DOFS]
    chat, rmse = fr.chat.mean(axis=0), fr.rmse.mean(axis=0)  # over draws (one draw: that draw)
    rows = []
    for i in range(fr.size):  # G: the largest constraint value (the one constraint of the paper's studies)
        rows.append([i, int(fr.index[i]), *[float(x) for x in fr.F[i]], float(fr.G[i].max()), i == knee]
                    + [float(x) for x in fr.gains[i]] + [float(x) for x in chat[i]] + [float(x) for x in rmse[i]])
    return head, rows


def export_front(path: str | Path, fmt: str) -> str:
    """The front as CSV or JSON text (floats in shortest round-trip form: reading them back is exact).

    CSV: one row per member: ``member, population_row, f_chat, f_rmse`` (or the study's ``f_<objective>``),
    ``G, knee``, the gains by name,
    then per-DOF CHAT and RMSE (mean over the draws). JSON: the same members plus provenance (study,
    seed, draws, reference point, hypervolume, Table 2's objectives, versions).
    """
    if fmt not in ("csv", "json"):
        raise ValueError(f"--format: unknown '{fmt}' (allowed: csv, json)")
    fr = read_front(path)
    head, rows = _records(fr)
    if fmt == "csv":
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(head)
        for r in rows:
            w.writerow([repr(x) if isinstance(x, float) else x for x in r])
        return buf.getvalue()
    members = []
    m, g = len(fr.labels), 4 + len(fr.labels)  # g: the first gain's column
    for r in rows:
        members.append({
            "member": r[0], "population_row": r[1], **dict(zip(fr.labels, r[2:2 + m])), "G": r[2 + m],
            "knee": r[3 + m], "gains": dict(zip(fr.names, r[g:g + len(fr.names)])),
            "chat": r[g + len(fr.names):g + 6 + len(fr.names)], "rmse": r[g + 6 + len(fr.names):],
        })
    doc = {
        "format": "arvcas.tuning.front.export", "format_version": 1, "controller": fr.controller,
        "study": fr.study_name, "status": fr.status, "generations": fr.n_gen, "evaluations": fr.n_eval,
        "seed": fr.seed, "objectives": fr.labels,
        "draws": [{"noise_seed": int(s), "uncertainty": u.tolist(), "phase_rad": p.tolist()}
                  for s, u, p in zip(fr.draw_seeds, fr.draw_uncertainty, fr.draw_phase)],
        "reference_point": fr.reference_point.tolist(), "hypervolume": fr.hv,
        "table2": {**{lab: _num(v) for lab, v in zip(fr.labels, fr.table2_F)}, "G": _num(np.max(fr.table2_G)),
                   "gains": dict(zip(fr.names, fr.table2.tolist()))},
        "knee": fr.knee() if fr.size else None, "gain_names": fr.names, "dofs": list(DOFS), "members": members,
        "versions": fr.versions,
    }
    if fr.plugin:
        doc["plugin"] = fr.plugin
    return json.dumps(doc, indent=1) + "\n"


def _num(x):
    x = float(x)
    return x if np.isfinite(x) else None


# ---- plot --------------------------------------------------------------------------------------------


def _paper_points():
    t = table3()
    return (1.0, 1.0), (float(np.mean(t.chat_proposed / t.chat_agsta)), float(np.mean(t.rmse_proposed / t.rmse_agsta)))


def plot_fronts(fronts, ax=None, labels=None, population: bool = True, paper: bool = False):
    """Several fronts in one axes (f_chat vs f_rmse): fronts, the default gains on the same draws (Table 2
    for Haidou-1), knees; in the house style (:mod:`arvcas.io.style`), column width.

    ``population``: the feasible members of the last population, faint; ``paper``: the paper's
    Table 3 points (AGSTA = (1, 1) by construction, and the proposed controller), from its simulator
    (Haidou-1's fronts only: the paper's table is of Haidou-1).
    """
    from arvcas.io import style

    fronts = list(fronts)
    if any(fr.objectives != fronts[0].objectives for fr in fronts):
        raise ValueError("plot: the fronts have different objectives (" + "; ".join(
            ", ".join(fr.objectives) for fr in fronts) + ")")
    if len(fronts[0].objectives) != 2 or fronts[0].objectives != ("chat", "rmse"):
        if paper:
            raise ValueError("--paper: the paper's Table 3 points are of f_chat and f_rmse alone")
        return _plot_pairs(fronts, labels, population)
    if paper and any(fr.system for fr in fronts):
        raise ValueError("--paper: the paper's Table 3 points are Haidou-1's; these fronts are of "
                         f"{', '.join(sorted({fr.system for fr in fronts if fr.system}))}")

    @style.styled
    def draw(ax):
        from arvcas.io.plots import controller_color

        own = ax is None
        if own:  # a bare Figure: no pyplot state, no GUI backend
            fig = style.figure("column", 3.0 + 0.35 * len(fronts) + (0.3 if paper else 0.0))
            ax = fig.add_subplot()
        else:
            fig = ax.figure
        distinct = len({fr.controller for fr in fronts}) == len(fronts)
        dname = "default" if any(fr.system for fr in fronts) else "Table 2"
        for j, fr in enumerate(fronts):
            col = controller_color(fr.controller, j) if distinct else style.color("", j)
            lab = labels[j] if labels else fr.controller
            if population:
                feas = fr.population_G[:, 0] <= 0
                P = fr.population_F[feas]
                ax.scatter(P[:, 0], P[:, 1], s=4, color=col, alpha=0.25, linewidths=0)
            if fr.size:
                ax.plot(fr.F[:, 0], fr.F[:, 1], "-o", color=col, ms=2.0, lw=0.8,
                        label=f"{lab}: {fr.size} members, HV {fr.hv:.4g}")
                k = fr.knee()
                ax.plot(fr.F[k, 0], fr.F[k, 1], "D", color=col, ms=5, mec="k", mew=0.6,
                        label=f"{lab}: knee ({fr.F[k, 0]:.3g}, {fr.F[k, 1]:.3g})")
            if np.isfinite(fr.table2_F).all():
                ax.plot(fr.table2_F[0], fr.table2_F[1], "*", color=col, ms=8, mec="k", mew=0.5,
                        label=f"{lab}: {dname} gains")
        if paper:
            a, p = _paper_points()
            ax.plot(*a, "s", mfc="none", mec="0.3", ms=5, label="paper Table 3 AGSTA (their simulator)")
            ax.plot(*p, "^", mfc="none", mec="0.3", ms=5, label="paper Table 3 proposed (their simulator)")
        norm = _norm_label(fronts)
        ax.set_xlabel(f"f_chat: CHAT / {norm}")
        ax.set_ylabel(f"f_rmse: RMSE / {norm}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        style.log_labels(ax)
        ax.grid(True, which="both", alpha=0.3)
        if own:  # below the axes, clear of the fronts
            fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncols=2, fontsize=6)
        else:
            ax.legend(fontsize=6, loc="best")
        return fig

    return draw(ax)


def _norm_label(fronts) -> str:
    """The axes' word for the objectives' reference: the fronts' recorded normalisation (compare refuses fronts
    normalised differently), or for fronts that predate the record, the rule of their day."""
    rec = {fr.normalisation for fr in fronts} - {""}
    if len(rec) == 1:
        (n,) = rec
        if n.startswith("the study's objectives.normalisation_chat"):
            return "the study's reference values"
        if "'s value at the default gains of " in n:
            return f"{n.split(chr(39) + 's value', 1)[0]} at its defaults"
    return "paper's AGSTA" if not any(fr.system for fr in fronts) else "AGSTA at its defaults"


def _plot_pairs(fronts, labels=None, population: bool = True):
    """Fronts of m objectives other than the paper's two: one panel per pair of objectives (m = 3: three
    panels), each front's members, its knee (diamond) and the default gains (star); log axes where the
    values are positive and span more than a decade."""
    from itertools import combinations

    from arvcas.io import style
    from arvcas.io.plots import controller_color

    labs = fronts[0].labels
    pairs = list(combinations(range(len(labs)), 2))

    @style.styled
    def draw(_):
        fig = style.figure("page", 2.4 * ((len(pairs) + 2) // 3) + 0.6)
        axes = fig.subplots((len(pairs) + 2) // 3, min(3, len(pairs)), squeeze=False).ravel()
        distinct = len({fr.controller for fr in fronts}) == len(fronts)
        for ax, (a, b) in zip(axes, pairs):
            for j, fr in enumerate(fronts):
                col = controller_color(fr.controller, j) if distinct else style.color("", j)
                lab = labels[j] if labels else fr.controller
                if population:
                    feas = (fr.population_G <= 0).all(axis=1) & np.isfinite(fr.population_F).all(axis=1)
                    ax.scatter(fr.population_F[feas, a], fr.population_F[feas, b], s=4, color=col, alpha=0.25,
                               linewidths=0)
                if fr.size:
                    ax.scatter(fr.F[:, a], fr.F[:, b], s=8, color=col, label=f"{lab}: {fr.size} members, HV {fr.hv:.4g}")
                    k = fr.knee()
                    ax.plot(fr.F[k, a], fr.F[k, b], "D", color=col, ms=5, mec="k", mew=0.6, label=f"{lab}: knee")
                if np.isfinite(fr.table2_F).all():
                    ax.plot(fr.table2_F[a], fr.table2_F[b], "*", color=col, ms=8, mec="k", mew=0.5,
                            label=f"{lab}: default gains")
            ax.set_xlabel(labs[a])
            ax.set_ylabel(labs[b])
            logs = 0
            for axis, i in ((ax.set_xscale, a), (ax.set_yscale, b)):
                vals = np.concatenate([fr.F[:, i] for fr in fronts])
                if vals.size and (vals > 0).all() and vals.max() > 10 * vals.min():  # log where a decade is spanned
                    axis("log")
                    logs += 1
            if logs:
                style.log_labels(ax)
            ax.grid(True, which="both", alpha=0.3)
        for ax in axes[len(pairs):]:
            ax.set_visible(False)
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=3, fontsize=6)
        return fig

    return draw(None)


def plot_front(front: Front | str | Path, ax=None, **kw):
    """One front: population (light), front, knee (diamond), the default gains on the same draws (star)."""
    fr = front if isinstance(front, Front) else read_front(front)
    fig = plot_fronts([fr], ax=ax, **kw)
    fig.axes[0].set_title(f"{fr.controller}: {fr.study_name}, {fr.n_gen} generations, {fr.n_eval} runs",
                          fontsize=7)
    return fig


# ---- provenance -------------------------------------------------------------------------------------


def system_params(c: ck.Checkpoint):
    """The parameters of the system a checkpoint's study ran on (Haidou-1's when it names none; with
    instantaneous thrusters when its ``system_variant`` says so)."""
    from arvcas.system.params import load
    from arvcas.system import load_system

    p = load_system(c.system).params if c.system else load()
    return p.instantaneous() if c.system_variant == "instantaneous" else p


def _same(p, c: ck.Checkpoint) -> bool:
    v = p.vector()
    return v.shape == c.params.shape and np.array_equal(v, c.params)


def _replay_params(c: ck.Checkpoint, path: Path):
    """(the parameters a replay of ``c`` runs on, the system variant they are): the system's, or, for a
    study of a system whose file has since gained thruster dynamics, its instantaneous variant when
    that has exactly the study's parameter vector (the replay then checks every number)."""
    p = system_params(c)
    if _same(p, c):
        return p, c.system_variant
    if not c.system_variant and _same(p.instantaneous(), c):
        return p.instantaneous(), "instantaneous"
    raise ck.CheckpointError(f"{path}: the study used other parameter values than the packaged system's "
                             f"({c.params.size} values, {p.vector().size} now); a replay cannot reproduce it")


def check_provenance(path: str | Path, params, allow: bool, what: str) -> str:
    """Refuse to re-run a front's members under another compiled run or parameters (``params``: a
    :class:`arvcas.system.params.Params`) than the study's (:func:`arvcas.tuning.checkpoint.provenance_diff`):
    the stored numbers would not be reproduced. With ``allow`` returns what differs (empty if nothing),
    for the output to record."""
    path = resolve_front_path(path)
    c = ck.read_checkpoint(path)
    diff = ck.provenance_diff(c, params, str(path))
    if diff and not allow:
        unknown = all(d.endswith(ck.restamp_hint(str(path))) for d in diff)  # an older file: not known to differ
        raise ck.CheckpointError(f"{what} {path}: {'; '.join(diff)}"
                                 + ("" if unknown else "; a re-run would not reproduce the study")
                                 + " (--allow-model-change to run anyway; the output records it)")
    return "; ".join(diff)


def check_same_model(a: str | Path, b: str | Path, allow: bool) -> str:
    """Refuse to compare two fronts computed with different model code, data or parameters; with
    ``allow`` returns what differs (empty if nothing). Two fronts written by the same source (equal model
    hashes) compare; so do two whose runs both replay on today's code (:func:`ck.provenance_diff`)."""
    pa, pb = resolve_front_path(a), resolve_front_path(b)
    ca, cb = ck.read_checkpoint(pa), ck.read_checkpoint(pb)
    why = []
    if ca.model_hash != cb.model_hash:
        stale = [f"{p}: {'; '.join(d)}" for p, c in ((pa, ca), (pb, cb))
                 for d in [ck.provenance_diff(c, system_params(c), str(p))] if d]
        if stale:
            why.append(f"model hash {ca.model_hash[:12] or 'none'} vs {cb.model_hash[:12] or 'none'}, and "
                       + "; ".join(stale))
    if ca.params.shape != cb.params.shape or not np.array_equal(ca.params, cb.params):
        why.append("different parameter vectors")
    da, db = ca.plugin.get("digest", ""), cb.plugin.get("digest", "")
    if ca.controller == cb.controller and da != db:
        why.append(f"controller {ca.controller} from different source (sha256 {da[:12] or 'none'} vs {db[:12] or 'none'})")
    if why and not allow:
        raise ck.CheckpointError(f"compare: {a} and {b} were computed with different models ({', '.join(why)}); "
                                 f"their objectives are not comparable (--allow-model-change to compare anyway)")
    return ", ".join(why)


# ---- replay ------------------------------------------------------------------------------------------


def _member(fr: Front, index: int, what: str = "--index") -> int:
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)):
        raise ValueError(f"{what}: expected an integer, got {index!r}")
    if not -fr.size <= index < fr.size:
        raise ValueError(f"{what} {index}: {fr.path} has {fr.size} front member(s) (0..{fr.size - 1})")
    return int(index) % fr.size


def member_index(fr: Front, member, what: str = "--member") -> int:
    """The front index of ``member``: ``"knee"`` (:meth:`Front.knee`, the rule of ``arvcas knees``) or an
    integer (members sorted by f_chat; negative counts from the end)."""
    return fr.knee() if member == "knee" else _member(fr, member, what)


def member_gains(path: str | Path, index: int):
    """``(controller, gains, seed, scenario text)`` of front member ``index`` (sorted by f_chat).

    Replaying these with :func:`arvcas.sim.simulation.simulate` (the gains, the noise seed, the scenario
    text, the packaged parameters) reproduces the member's stored per-DOF CHAT and RMSE, and so its
    objectives, bit for bit. Only for single-draw studies that use the scenario's own uncertainty
    factors and phases; otherwise use :func:`replay`.
    """
    fr = read_front(path)
    i = _member(fr, index)
    ck.controller_of(fr, str(fr.path))  # a plugin's controller: loaded, or which plugin to load
    if fr.draw_seeds.size != 1:
        raise ValueError(f"{fr.path}: the objectives average {fr.draw_seeds.size} draws; one simulate run cannot "
                         f"reproduce them (use arvcas.tuning.front.replay)")
    from arvcas.sim.scenario import loads_scenario

    cfg = loads_scenario(fr.scenario_text, f"{fr.path} (study scenario)")
    if not (np.array_equal(fr.draw_uncertainty[0], cfg.uncertainty)
            and np.array_equal(fr.draw_phase[0], np.array(cfg.disturbance_phase))):
        raise ValueError(f"{fr.path}: the study's draw sets its own uncertainty factors or phases; a plain simulate "
                         f"run cannot reproduce it (use arvcas.tuning.front.replay)")
    return fr.controller, fr.gains[i].copy(), int(fr.draw_seeds[0]), fr.scenario_text


def _task(fr: Front, c: ck.Checkpoint, params):
    """(the study's :class:`~arvcas.tuning.engines.EvalTask`, its objectives for
    :func:`~arvcas.tuning.run.evaluate_gains`) on ``params``: its controller, draws, scenario,
    normalisation, CHAT signal and objectives, as the study evaluated them."""
    from arvcas.sim.scenario import loads_scenario
    from arvcas.tuning.engines import EvalTask

    cfg = loads_scenario(fr.scenario_text, f"{fr.path} (study scenario)")
    draws = tuple((int(s), u, ph) for s, u, ph in zip(fr.draw_seeds, fr.draw_uncertainty, fr.draw_phase))
    ref = None if c.ref_chat is None else (tuple(c.ref_chat), tuple(c.ref_rmse))
    obj = ck.objectives_of(c)
    task = EvalTask(controller=fr.controller, draws=draws, cfg=cfg, params=params, ref=ref, chat=obj.chat,
                    accumulators=obj.accumulators())
    return task, (obj.objects() if task.accumulators else None)


def _evaluate(fr: Front, c: ck.Checkpoint, params, gains: np.ndarray, n_threads: int | None):
    """:func:`~arvcas.tuning.run.evaluate_gains` of the gain sets ``gains`` as the study evaluated its members."""
    from arvcas.tuning.engines import LocalEngine
    from arvcas.tuning.run import evaluate_gains

    task, objs = _task(fr, c, params)
    return evaluate_gains(LocalEngine(n_threads or 1), task, gains, objs)


def replay(path: str | Path, index: int, n_threads: int | None = None):
    """Re-evaluate front member ``index`` on all the study's draws (same code path as the study).

    Returns the :class:`~arvcas.tuning.problem.Evaluation` of that one member (F, G, per-DOF metrics).
    """
    fr = read_front(path)
    i = _member(fr, index)
    c = ck.read_checkpoint(resolve_front_path(path))
    p = system_params(c)
    check_provenance(fr.path, p, False, "replay")
    return _evaluate(fr, c, p, fr.gains[i][None, :], n_threads)


@dataclass
class Replayed:
    """What :func:`replay_all` found: the worst absolute differences of the replayed objectives (``F``)
    and per-DOF CHAT and RMSE (``metrics``) from the stored ones, over ``members`` front members (and the
    default gains if ``defaults``); ``run_digest`` of today's run."""

    path: Path
    members: int
    defaults: bool
    F: float
    metrics: float
    run_digest: str
    system_variant: str = ""

    @property
    def bitwise(self) -> bool:
        return self.F == 0.0 and self.metrics == 0.0

    def what(self) -> str:
        return (f"the knee" if self.members == 1 and not self.defaults else
                f"{self.members} front members" + (" and the default gains" if self.defaults else ""))

    def describe(self) -> str:
        if self.bitwise:
            return f"{self.path}: {self.what()}: replayed bit for bit (run digest {self.run_digest[:12]})"
        return (f"{self.path}: {self.what()}: replayed with max |difference| {self.F:.3g} in the objectives, "
                f"{self.metrics:.3g} in the per-DOF CHAT/RMSE (run digest {self.run_digest[:12]})")


def _differ(a, b) -> float:
    """Worst absolute difference of two arrays (inf where one is NaN and the other not, 0 where both are)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        return float("inf")
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    if np.any(nan_a != nan_b):
        return float("inf")
    d = np.abs(a[~nan_a] - b[~nan_b])
    return float(d.max()) if d.size else 0.0


def replay_all(path: str | Path, members="all", n_threads: int | None = None, chunk: int = 32) -> Replayed:
    """Replay front members on today's code (no provenance check: this is the check) and compare their
    objectives and per-DOF metrics with the stored ones. ``members``: ``"all"`` (every member and the
    default gains) or ``"knee"`` (the knee alone). Evaluated ``chunk`` gain sets at a time (below
    :data:`arvcas.sim.run.LOCKSTEP_MIN_RUNS`: no lockstep library is built; its outputs equal the scalar
    run's to the bit, tests/test_lockstep.py)."""
    path = resolve_front_path(path)
    fr = read_front(path)
    c = ck.read_checkpoint(path)
    ck.controller_of(c, str(path))
    p, variant = _replay_params(c, path)
    if fr.size == 0:
        raise ck.CheckpointError(f"{path}: the front is empty: nothing to replay")
    if members == "knee":
        rows = [fr.knee()]
        gains, F_ref = fr.gains[rows], fr.F[rows]
        chat_ref, rmse_ref = fr.chat[:, rows], fr.rmse[:, rows]
    elif members == "all" and c.table2_chat is None:  # written before the defaults were evaluated
        gains, F_ref, chat_ref, rmse_ref = fr.gains, fr.F, fr.chat, fr.rmse
    elif members == "all":
        gains = np.vstack([fr.gains, fr.table2[None, :]])
        t2F = fr.table2_F if fr.table2_F.size == fr.F.shape[1] else np.full(fr.F.shape[1], np.nan)
        F_ref = np.vstack([fr.F, t2F[None, :]])
        chat_ref = np.concatenate([fr.chat, c.table2_chat[:, None, :]], axis=1)
        rmse_ref = np.concatenate([fr.rmse, c.table2_rmse[:, None, :]], axis=1)
    else:
        raise ValueError(f"members: 'all' or 'knee', got {members!r}")
    evs = [_evaluate(fr, c, p, gains[i:i + chunk], n_threads) for i in range(0, len(gains), chunk)]
    F = np.vstack([e.F for e in evs])
    chat = np.concatenate([e.chat for e in evs], axis=1)
    rmse = np.concatenate([e.rmse for e in evs], axis=1)
    return Replayed(path, len(fr.gains) if members == "all" else 1, len(gains) > len(fr.gains), _differ(F, F_ref),
                    max(_differ(chat, chat_ref), _differ(rmse, rmse_ref)), ck.run_digest(c, p), variant)


def restamp(path: str | Path, n_threads: int | None = None) -> Replayed:
    """Record today's run digest in a front whose every member and default gains replay bit for bit on
    today's code (:func:`replay_all`); nothing else in the file changes (its objectives, its ``updated``)
    but, for a study whose system file has since gained thruster dynamics, ``system_variant`` (the variant
    the replay found); ``restamps`` records when, the digest and what replayed. Refuses (one line) if any
    number differs: such a front must be re-run, not re-stamped. A front already stamped with today's
    digest is left as it is."""
    path = resolve_front_path(path)
    c = ck.read_checkpoint(path)
    r = replay_all(path, "all", n_threads)
    if not r.bitwise:
        raise ck.CheckpointError(f"front restamp: {r.describe()}: not re-stamped; re-run the study "
                                 f"(arvcas tune) to get a front of today's code")
    if c.run_digest == r.run_digest and c.system_variant == r.system_variant:
        return r
    from arvcas.build.provenance import model_hash

    c.restamps = list(c.restamps) + [{
        "time": ck._now(), "run_digest": r.run_digest, "previous_run_digest": c.run_digest,
        "model_hash": model_hash(), "replayed": r.what() + ", bit for bit",
        **({"system_variant": r.system_variant} if r.system_variant != c.system_variant else {})}]
    c.run_digest, c.system_variant = r.run_digest, r.system_variant
    ck.write_checkpoint(c, path, touch=False)
    return r
