"""Robust fronts: every member of a tuning front re-evaluated under Monte Carlo.

A tuning study (``arvcas.tuning``) ranks candidates on one draw (or a few): one noise sequence,
one set of nominal-model factors, one set of disturbance phases. :func:`robust_front` re-runs every
front member, and the system's default gains for reference (Haidou-1: Table 2), on ``runs`` draws of
:mod:`.montecarlo`
(the same draws for every member: the comparison between members is paired) and reports per member

- ``F_mean``: docs/model.md §7 objectives (f_chat, f_rmse) averaged over the draws that completed, with
  their 95 % t-intervals; the failure count (diverged draws) with its Wilson interval;
- ``robust_nd``: the member has no failed draw and no other such member is at least as good in both
  mean objectives and better in one (non-dominated on the Monte Carlo means);
- ``certainly_dominated``: some other member with no failed draw is better in both objectives with
  95 % confidence (the paired t-interval of the per-draw difference lies below 0 for f_chat and for
  f_rmse; no multiple-comparison correction).

Members are read through :func:`arvcas.tuning.front.read_front` (front order: by one-draw f_chat).
The study's own scenario (``Front.scenario_text``) and system are used; the parameters must be the
packaged ones the study used (checked); the objectives are normalised as the study's (Haidou-1: the
paper's Table 3 AGSTA values; another system: its AGSTA at its default gains, stored in the file). File layout (``format = "arvcas-robust-front"``, ``format_version = 1``):
datasets ``gains`` (f, m), ``F_front`` (f, 2, the study's objectives), ``F_mean`` (f, 2), ``F_lo``,
``F_hi``, ``n_fail`` (f,), ``robust_nd``, ``certainly_dominated`` (f,), per-run ``chat``/``rmse``
(f, runs, 6) and ``ok`` (f, runs), ``table2/...`` (the same for the default gains), the draws
(``noise_seed``, ``factors``, ``phase``); attributes ``front_path``, ``controller``, ``study_name``,
``knee`` (the study's knee member), ``master_seed``, ``runs``, ``spread``, ``draw_rule``, ``config``,
``params``, versions; for another system than Haidou-1 also ``system``, ``param_names`` and the
normalisation ``ref_chat``, ``ref_rmse``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from arvcas.controllers import gains as gains_mod
from arvcas.metrics import indices as metrics
from arvcas.sim import scenario
from arvcas.io import style
from arvcas.system.params import SCHEMA as PARAM_SCHEMA
from arvcas.sim.simulation import simulate_many
from arvcas.experiments import _io
from arvcas.experiments.montecarlo import CHUNK, DRAW_RULE, Draws, draw
from arvcas.experiments.stats import mean_ci, paired_ci, wilson

__all__ = ["RobustFront", "front_member", "robust_front", "write_robust", "read_robust", "robust_markdown",
           "plot_robust", "write_robust_dir", "compare_robust", "compare_robust_markdown", "plot_compare_robust",
           "is_robust_file", "FORMAT", "FORMAT_VERSION"]

FORMAT = "arvcas-robust-front"
FORMAT_VERSION = 1


def _front(path):
    from arvcas.tuning.front import read_front

    return read_front(path)


def front_member(path, index) -> tuple[str, np.ndarray, str, str]:
    """``(controller, gains, scenario text, description)`` of front member ``index`` (an integer in
    the front's order, or ``"knee"`` for the study's knee point, :meth:`arvcas.tuning.front.Front.knee`)."""
    fr = _front(path)
    if isinstance(index, str) and index.strip().lower() == "knee":
        i = fr.knee()
        what = f"knee (member {i})"
    else:
        try:
            i = int(index)
        except (TypeError, ValueError):
            raise ValueError(f"--index: expected an integer or 'knee', got {index!r}") from None
        if not -fr.size <= i < fr.size:
            raise ValueError(f"--index {i}: {fr.path} has {fr.size} front member(s) (0..{fr.size - 1})")
        i %= fr.size
        what = f"member {i}"
    return fr.controller, fr.gains[i].copy(), fr.scenario_text, f"'{fr.study_name}' front {what}"


@dataclass
class RobustFront:
    """Monte Carlo re-evaluation of a front (module docstring). Arrays over the f members."""

    front_path: str
    controller: str
    study_name: str
    knee: int
    draws: Draws
    gains: np.ndarray  # (f, m)
    F_front: np.ndarray  # (f, 2): the study's own objectives
    chat: np.ndarray  # (f, runs, 6)
    rmse: np.ndarray  # (f, runs, 6)
    ok: np.ndarray  # (f, runs)
    table2_gains: np.ndarray
    table2_F_front: np.ndarray  # (2,)
    table2_chat: np.ndarray  # (runs, 6)
    table2_rmse: np.ndarray
    table2_ok: np.ndarray
    config_text: str
    params_vector: np.ndarray
    model_change: str = ""  # what changed since the study, when that was allowed (empty: nothing)
    system: str = ""  # the study's system ("": Haidou-1)
    ref: tuple | None = None  # the objectives' per-DOF (chat, rmse) normalisation (None: the paper's Table 3)
    param_names: tuple = ()  # another system's parameter names (Haidou-1: the packaged schema)

    @property
    def size(self) -> int:
        return int(self.gains.shape[0])

    @property
    def defaults_name(self) -> str:
        """How the reference gains are named: "Table 2" (Haidou-1) or "defaults"."""
        return "Table 2" if not self.system else "defaults"

    def per_run_objectives(self) -> np.ndarray:
        """(f + 1, runs, 2): docs/model.md §7 objectives per member and draw (last row: the default gains);
        NaN if diverged."""
        C = np.concatenate([self.chat, self.table2_chat[None]], axis=0)
        R = np.concatenate([self.rmse, self.table2_rmse[None]], axis=0)
        rc, rr = metrics.reference_values(self.ref)
        with np.errstate(invalid="ignore"):
            return np.stack([np.mean(C / rc, axis=2), np.mean(R / rr, axis=2)], axis=2)

    def stats(self) -> dict[str, np.ndarray]:
        """``F_mean``, ``F_lo``, ``F_hi`` (f + 1, 2), ``n_fail`` (f + 1,), ``robust_nd``,
        ``certainly_dominated`` (f,): members first, the default gains last (not part of the front)."""
        O = self.per_run_objectives()
        ok = np.concatenate([self.ok, self.table2_ok[None]], axis=0)
        n = O.shape[0]
        mean, lo, hi = (np.full((n, 2), np.nan) for _ in range(3))
        for i in range(n):
            for j in range(2):
                iv = mean_ci(O[i, :, j])
                mean[i, j], lo[i, j], hi[i, j] = iv.estimate, iv.lo, iv.hi
        n_fail = (~ok).sum(axis=1)
        f = self.size
        sound = n_fail[:f] == 0
        nd = np.zeros(f, dtype=bool)
        for i in np.flatnonzero(sound):
            others = [k for k in np.flatnonzero(sound) if k != i]
            dom = [np.all(mean[k] <= mean[i]) and np.any(mean[k] < mean[i]) for k in others]
            nd[i] = not any(dom)
        cert = np.zeros(f, dtype=bool)
        for i in range(f):
            for k in np.flatnonzero(sound):
                if k == i:
                    continue
                if all(paired_ci(O[k, :, j], O[i, :, j]).hi < 0 for j in range(2)):
                    cert[i] = True
                    break
        return {"F_mean": mean, "F_lo": lo, "F_hi": hi, "n_fail": n_fail, "robust_nd": nd,
                "certainly_dominated": cert}


def robust_front(path, runs: int, seed: int = 0, spread: float = 0.3, n_threads: int | None = None,
                 progress: Callable[[str], None] | None = None, model_change: str = "") -> RobustFront:
    """Re-evaluate every member of the front in ``path`` (and the default gains) on ``runs`` Monte Carlo draws.

    The study's model and parameters must be this installation's
    (:func:`arvcas.tuning.front.check_provenance`) unless ``model_change`` says what changed and that
    it was allowed (recorded in the file as ``model_change_allowed``)."""
    fr = _front(path)
    if fr.size == 0:
        raise ValueError(f"{fr.path}: the front is empty")
    d = draw(runs, seed, spread)
    cfg = scenario.loads_scenario(fr.scenario_text, f"{fr.path} (study scenario)") if fr.scenario_text \
        else scenario.load_scenario()
    from arvcas.tuning import checkpoint as ck
    from arvcas.tuning.front import check_provenance, system_params

    cp = ck.read_checkpoint(fr.path)
    params = system_params(cp)
    if not model_change:
        check_provenance(fr.path, params, False, "front robust")
    c = fr.controller
    table2 = gains_mod.default_gains(c, params)
    G = np.vstack([fr.gains, table2[None]])  # members, then the default gains
    m = G.shape[0]
    rows_g = np.repeat(G, d.runs, axis=0)
    rows_s = np.tile(d.noise_seed, m)
    rows_u = np.tile(d.factors, (m, 1))
    rows_p = np.tile(d.phase, (m, 1))
    n = rows_g.shape[0]
    chat, rmse, ok = np.full((n, 6), np.nan), np.full((n, 6), np.nan), np.zeros(n, dtype=bool)
    for a in range(0, n, CHUNK):
        b = min(n, a + CHUNK)
        if progress:
            progress(f"{c}: {fr.size} members + {metrics.defaults_name(fr.system)} x {d.runs} draws: "
                     f"runs {a}..{b - 1} of {n}")
        c_, r_, o_, _t = simulate_many(c, rows_g[a:b], rows_s[a:b], uncertainty=rows_u[a:b], phase=rows_p[a:b],
                                       system=params, cfg=cfg, n_threads=n_threads)
        chat[a:b], rmse[a:b], ok[a:b] = c_, r_, o_
    chat, rmse, ok = chat.reshape(m, d.runs, 6), rmse.reshape(m, d.runs, 6), ok.reshape(m, d.runs)
    return RobustFront(
        front_path=str(fr.path), controller=c, study_name=fr.study_name, knee=fr.knee(), draws=d,
        gains=fr.gains.copy(), F_front=fr.F.copy(), chat=chat[:-1], rmse=rmse[:-1], ok=ok[:-1],
        table2_gains=table2, table2_F_front=np.asarray(fr.table2_F, float), table2_chat=chat[-1],
        table2_rmse=rmse[-1], table2_ok=ok[-1], config_text=cfg.to_toml(), params_vector=params.vector(),
        model_change=model_change, system=fr.system,
        ref=None if cp.ref_chat is None else (tuple(cp.ref_chat), tuple(cp.ref_rmse)),
        param_names=tuple(params.names()) if fr.system else (),
    )


# ---------------------------------------------------------------------------------------------
# file


_ARRAYS = ("gains", "F_front", "chat", "rmse", "ok")
_T2 = ("table2_gains", "table2_F_front", "table2_chat", "table2_rmse", "table2_ok")


def write_robust(rf: RobustFront, path) -> Path:
    import h5py

    path = _io.target(path, str(path))
    st = rf.stats()

    def fill(tmp: Path) -> None:
        with _io.files.new_hdf5(tmp) as f:
            a = f.attrs
            a["format"], a["format_version"] = FORMAT, FORMAT_VERSION
            a["front_path"], a["controller"], a["study_name"] = rf.front_path, rf.controller, rf.study_name
            a["knee"] = int(rf.knee)
            a["master_seed"], a["runs"], a["spread"] = int(rf.draws.master_seed), int(rf.draws.runs), rf.draws.spread
            a["draw_rule"] = DRAW_RULE
            a["config"] = rf.config_text
            a["params"] = np.asarray(rf.params_vector, float)
            a["param_names"] = np.array(list(rf.param_names or PARAM_SCHEMA), dtype=object)
            a["gain_names"] = np.array(gains_mod.gain_names(rf.controller), dtype=object)
            if rf.model_change:
                a["model_change_allowed"] = rf.model_change
            if rf.system:
                a["system"] = rf.system
            if rf.ref is not None:
                a["ref_chat"], a["ref_rmse"] = (np.asarray(x, float) for x in rf.ref)
            a["objectives"] = (f"f_chat, f_rmse (docs/model.md §7: per-DOF value / {metrics.norm_name(rf.system)}, "
                               "mean over 6 DOF)")
            for k, v in _io.provenance().items():
                a[k] = v
            for k in _ARRAYS:
                f.create_dataset(k, data=getattr(rf, k))
            for k in _T2:
                f.create_dataset(k.replace("table2_", "table2/"), data=getattr(rf, k))
            f.create_dataset("noise_seed", data=rf.draws.noise_seed)
            f.create_dataset("factors", data=rf.draws.factors)
            f.create_dataset("phase", data=rf.draws.phase)
            for k in ("F_mean", "F_lo", "F_hi", "n_fail"):  # members first, the default gains as the last row
                f.create_dataset(k, data=st[k]).attrs["rows"] = ("front members in front order, then the "
                                                                 + metrics.defaults_name(rf.system))
            f.create_dataset("robust_nd", data=st["robust_nd"])
            f.create_dataset("certainly_dominated", data=st["certainly_dominated"])

    return _io.atomic_write(path, fill, FORMAT)


def read_robust(path) -> RobustFront:
    f = _io.open_h5(path, FORMAT, FORMAT_VERSION)
    try:
        a = f.attrs
        d = Draws(int(a["master_seed"]), float(a["spread"]), np.array(f["noise_seed"][()], dtype=np.int64),
                  np.array(f["factors"][()]), np.array(f["phase"][()]))
        return RobustFront(
            front_path=_io.str_attr(a["front_path"]), controller=_io.str_attr(a["controller"]),
            study_name=_io.str_attr(a["study_name"]), knee=int(a["knee"]), draws=d,
            **{k: np.array(f[k][()]) for k in _ARRAYS},
            **{k: np.array(f[k.replace("table2_", "table2/")][()]) for k in _T2},
            config_text=_io.str_attr(a["config"]), params_vector=np.array(a["params"]),
            model_change=_io.str_attr(a["model_change_allowed"]) if "model_change_allowed" in a else "",
            system=_io.str_attr(a["system"]) if "system" in a else "",
            ref=(tuple(np.array(a["ref_chat"], float)), tuple(np.array(a["ref_rmse"], float))) if "ref_chat" in a
            else None,
            param_names=tuple(_io.str_attr(x) for x in a["param_names"]) if "system" in a else (),
        )
    finally:
        f.close()


# ---------------------------------------------------------------------------------------------
# report


def robust_markdown(rf: RobustFront) -> str:
    st = rf.stats()
    M, lo, hi, nf = st["F_mean"], st["F_lo"], st["F_hi"], st["n_fail"]
    R = rf.draws.runs
    f = rf.size

    def ci(i, j):
        return f"{M[i, j]:.4g} [{lo[i, j]:.4g}, {hi[i, j]:.4g}]" if np.isfinite(M[i, j]) else "n/a"

    def fails(i):
        w = wilson(int(nf[i]), R)
        return f"{int(nf[i])}/{R} (≤ {w.hi:.2g})"

    n_nd, n_cd = int(st["robust_nd"].sum()), int(st["certainly_dominated"].sum())
    L = [f"# Robust front: {rf.controller}, study '{rf.study_name}'", "",
         f"Front `{rf.front_path}`: {f} members, each re-run with the {metrics.defaults_name(rf.system)} for "
         "reference on the same "
         f"{R} Monte Carlo draws (master seed {rf.draws.master_seed}; noise seed, nominal-model factors uniform "
         f"in [{1 - rf.draws.spread:g}, {1 + rf.draws.spread:g}], disturbance phases uniform in [0, 2π)). "
         "F front = the study's objectives (its own draw); MC mean = mean over the draws with 95 % t-interval; "
         "failures with the 95 % Wilson upper bound.", "",
         f"**{n_nd} of {f} members stay non-dominated** on the Monte Carlo means (robust ND, members without "
         f"failed draws); {n_cd} are certainly dominated (another member is better in both objectives, paired "
         "95 % intervals).", "",
         "| member | F front (f_chat, f_rmse) | MC f_chat [95 % CI] | MC f_rmse [95 % CI] | failures | robust ND "
         "| certainly dominated |", "|---:|---|---:|---:|---:|---|---|"]
    for i in range(f):
        tag = " (knee)" if i == rf.knee else ""
        L.append(f"| {i}{tag} | {rf.F_front[i, 0]:.4g}, {rf.F_front[i, 1]:.4g} | {ci(i, 0)} | {ci(i, 1)} | {fails(i)} "
                 f"| {'yes' if st['robust_nd'][i] else 'no'} | {'yes' if st['certainly_dominated'][i] else 'no'} |")
    t = f
    L.append(f"| {rf.defaults_name} | {rf.table2_F_front[0]:.4g}, {rf.table2_F_front[1]:.4g} | {ci(t, 0)} | {ci(t, 1)} "
             f"| {fails(t)} | (reference) | |")
    k = rf.knee
    L += ["", f"Knee (member {k}): one draw ({rf.F_front[k, 0]:.4g}, {rf.F_front[k, 1]:.4g}), Monte Carlo "
          f"({M[k, 0]:.4g}, {M[k, 1]:.4g}); robust ND: {'yes' if st['robust_nd'][k] else 'no'}.", ""]
    return "\n".join(L)


@style.styled
def plot_robust(rf: RobustFront, fig: Figure | None = None) -> Figure:
    """f_chat vs f_rmse: the study's one-draw front (hollow), each member's Monte Carlo mean with its
    95 % intervals (filled; robust non-dominated members ringed), the default gains (star), the knee (diamond)."""
    st = rf.stats()
    M, lo, hi = st["F_mean"], st["F_lo"], st["F_hi"]
    if fig is None:
        fig = style.figure("column", 3.4)
    ax = fig.add_subplot()
    f = rf.size
    blue, red, orange = style.color("tab:blue"), style.color("tab:red"), style.color("tab:orange")
    dname = rf.defaults_name
    ax.plot(rf.F_front[:, 0], rf.F_front[:, 1], "o", mfc="none", mec="0.5", ms=3, label="front, study's draw")
    for i in range(f):
        ax.plot([rf.F_front[i, 0], M[i, 0]], [rf.F_front[i, 1], M[i, 1]], color="0.8", lw=0.4, zorder=1)
    ok = np.isfinite(M[:f, 0])
    ax.errorbar(M[:f][ok, 0], M[:f][ok, 1], xerr=[M[:f][ok, 0] - lo[:f][ok, 0], hi[:f][ok, 0] - M[:f][ok, 0]],
                yerr=[M[:f][ok, 1] - lo[:f][ok, 1], hi[:f][ok, 1] - M[:f][ok, 1]], fmt="o", color=blue,
                ms=2.5, lw=0.6, capsize=1.5, label=f"Monte Carlo mean, 95 % CI ({rf.draws.runs} draws)")
    nd = st["robust_nd"]
    ax.plot(M[:f][nd, 0], M[:f][nd, 1], "o", mfc="none", mec=red, ms=6, mew=0.9,
            label=f"robust non-dominated ({int(nd.sum())} of {f})")
    bad = st["n_fail"][:f] > 0
    if bad.any():
        ax.plot(M[:f][bad, 0], M[:f][bad, 1], "x", color=red, ms=5, mew=1.0,
                label=f"failed draws ({int(bad.sum())} members)")
    k = rf.knee
    ax.plot(M[k, 0], M[k, 1], "D", color=orange, mec="k", ms=5, mew=0.6, label=f"knee (member {k}), Monte Carlo")
    ax.plot(rf.F_front[k, 0], rf.F_front[k, 1], "D", mfc="none", mec=orange, ms=5, label="knee, study's draw")
    if np.isfinite(M[f]).all():
        ax.plot(M[f, 0], M[f, 1], "*", color="k", ms=8, label=f"{dname}, Monte Carlo")
    if np.isfinite(rf.table2_F_front).all():
        ax.plot(*rf.table2_F_front, "*", mfc="none", mec="k", ms=8, label=f"{dname}, study's draw")
    # axes from the front, the robust members, the knee and the defaults; members whose Monte Carlo mean lies
    # far outside (means dominated by a few extreme runs) are counted in the title, not drawn to scale
    key = np.vstack([rf.F_front, M[:f][nd], M[[k, f]], rf.table2_F_front[None]])
    key = key[np.all(np.isfinite(key), axis=1)]
    lo_k, hi_k = key.min(axis=0), key.max(axis=0)
    pad = 0.08 * (hi_k - lo_k)
    ax.set_xlim(lo_k[0] - pad[0], hi_k[0] + pad[0])
    ax.set_ylim(lo_k[1] - pad[1], hi_k[1] + pad[1])
    off = int(np.sum(np.isfinite(M[:f, 0]) & np.any((M[:f] < lo_k - pad) | (M[:f] > hi_k + pad), axis=1)))
    norm = metrics.norm_name(rf.system).removeprefix("the ")
    ax.set_xlabel(f"f_chat (mean CHAT / {norm})")
    ax.set_ylabel(f"f_rmse (mean RMSE / {norm})")
    extra = f"; {off} member(s) off the axes (Monte Carlo mean far larger)" if off else ""
    ax.set_title(f"{rf.controller}, study '{rf.study_name}': front under Monte Carlo{extra}", fontsize=7)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=6)
    return fig


def write_robust_dir(rf: RobustFront, out_dir, fmt: str = "png") -> dict[str, Path]:
    """``out_dir/robust.h5``, ``robust.md``, ``robust.png`` (or ``.pdf``, ``.svg``; atomic)."""
    return _io.write_result_dir(out_dir, "robust", rf, write_robust, robust_markdown, plot_robust, fmt)


# ---------------------------------------------------------------------------------------------
# two robust fronts (e.g. the proposed controller's and the AGSTA's)


def is_robust_file(path) -> bool:
    return _io.h5_format(path) == FORMAT


def _weakly_dominated(p: np.ndarray, S: np.ndarray) -> bool:
    return bool(len(S)) and bool(np.any(np.all(S <= p, axis=1)))


def compare_robust(a: RobustFront, b: RobustFront) -> dict:
    """Coverage of the two robust fronts (Monte Carlo means of the robust non-dominated members):
    ``cov_ab`` = fraction of B's members weakly dominated by some member of A, and ``cov_ba``;
    ``paired`` = both were evaluated on the same draws and scenario."""
    sa, sb = a.stats(), b.stats()
    A = sa["F_mean"][:a.size][sa["robust_nd"]]
    B = sb["F_mean"][:b.size][sb["robust_nd"]]
    cov_ab = float(np.mean([_weakly_dominated(p, A) for p in B])) if len(B) else float("nan")
    cov_ba = float(np.mean([_weakly_dominated(p, B) for p in A])) if len(A) else float("nan")
    paired = a.draws.same_as(b.draws) and a.config_text == b.config_text
    return {"A": A[np.argsort(A[:, 0])], "B": B[np.argsort(B[:, 0])], "cov_ab": cov_ab, "cov_ba": cov_ba,
            "paired": paired, "knee_a": sa["F_mean"][a.knee], "knee_b": sb["F_mean"][b.knee],
            "table2_a": sa["F_mean"][a.size], "table2_b": sb["F_mean"][b.size]}


def compare_robust_markdown(a: RobustFront, b: RobustFront) -> str:
    c = compare_robust(a, b)
    na, nb = f"{a.controller} ('{a.study_name}')", f"{b.controller} ('{b.study_name}')"
    same = ("on the same draws" if c["paired"] else "on DIFFERENT draws or scenarios (not a paired comparison)")
    L = [f"# Robust fronts: A = {na} vs B = {nb}", "",
         f"Monte Carlo means ({a.draws.runs} and {b.draws.runs} draws, {same}) of the members that stay "
         "non-dominated under Monte Carlo (robust ND, see robust.md of each).", "",
         f"- Coverage: {c['cov_ab'] * 100:.0f} % of B's {len(c['B'])} robust members are weakly dominated by one "
         f"of A's; {c['cov_ba'] * 100:.0f} % of A's {len(c['A'])} by one of B's.",
         f"- Knees (the studies' own knee members), Monte Carlo mean (f_chat, f_rmse): A ({c['knee_a'][0]:.4g}, "
         f"{c['knee_a'][1]:.4g}), B ({c['knee_b'][0]:.4g}, {c['knee_b'][1]:.4g}).",
         f"- {metrics.defaults_name(a.system)}, Monte Carlo mean: A ({c['table2_a'][0]:.4g}, {c['table2_a'][1]:.4g}), "
         f"B ({c['table2_b'][0]:.4g}, {c['table2_b'][1]:.4g}).", "",
         "Best Monte Carlo f_rmse each robust front attains at f_chat <= x:", "",
         "| x | A | B |", "|---:|---:|---:|"]
    xs = np.unique(np.concatenate([c["A"][:, 0], c["B"][:, 0]]))
    grid = np.quantile(xs, np.linspace(0, 1, 9)) if xs.size else []

    def best(S, x):
        v = S[S[:, 0] <= x, 1]
        return f"{v.min():.4g}" if v.size else "-"

    for x in grid:
        L.append(f"| {x:.4g} | {best(c['A'], x)} | {best(c['B'], x)} |")
    L.append("")
    return "\n".join(L)


@style.styled
def plot_compare_robust(a: RobustFront, b: RobustFront, fig: Figure | None = None) -> Figure:
    """Both robust fronts (Monte Carlo means, 95 % intervals), their knees and default-gain points."""
    if fig is None:
        fig = style.figure("column", 3.0)
    ax = fig.add_subplot()
    for rf, col in ((a, style.color("tab:blue")), (b, style.color("tab:red"))):
        st = rf.stats()
        f = rf.size
        nd = np.flatnonzero(st["robust_nd"])
        nd = nd[np.argsort(st["F_mean"][nd, 0])]
        M, lo, hi = st["F_mean"][nd], st["F_lo"][nd], st["F_hi"][nd]
        ax.errorbar(M[:, 0], M[:, 1], xerr=[M[:, 0] - lo[:, 0], hi[:, 0] - M[:, 0]],
                    yerr=[M[:, 1] - lo[:, 1], hi[:, 1] - M[:, 1]], fmt="-o", color=col, ms=2.5, lw=0.8, capsize=1.5,
                    label=f"{rf.controller}: robust front ({len(nd)} of {f})")
        k = rf.knee
        ax.plot(*st["F_mean"][k], "D", color=col, mec="k", ms=5, mew=0.6, label=f"{rf.controller}: knee (member {k})")
        ax.plot(*st["F_mean"][f], "*", color=col, mec="k", ms=8, mew=0.5, label=f"{rf.controller}: {rf.defaults_name}")
    ax.set_xlabel("f_chat, Monte Carlo mean")
    ax.set_ylabel("f_rmse, Monte Carlo mean")
    ax.set_title(f"Robust fronts ({a.draws.runs} / {b.draws.runs} draws)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=6)
    return fig
