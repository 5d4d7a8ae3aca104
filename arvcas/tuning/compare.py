"""Fronts side by side: hypervolume against one common reference point, and who dominates where.

Any number of fronts (two or more; A, B, C, ... in the order given):

* Hypervolume: pymoo's HV indicator for every front against the same reference point: by default
  the componentwise maximum of the studies' reference points (a valid reference for all);
  ``ref`` overrides it. Members that do not dominate the reference point add nothing.
* Coverage (Zitzler's C metric): for each pair, the fraction of one front's members weakly dominated
  by some member of the other.
* Where (two objectives): along the first, the attainment curve of each front (the best second objective
  reachable at or below that value); the intervals where one front's curve lies strictly below all the
  others'. Fronts of three or more objectives get hypervolume and coverage only.

Fronts of different objectives (docs/objectives.md) are not compared.
"""

from __future__ import annotations

import string
from dataclasses import dataclass

import numpy as np

from arvcas.tuning.front import Front, read_front
from arvcas.tuning.run import hypervolume

__all__ = ["Comparison", "compare_fronts", "format_comparison"]


@dataclass(frozen=True)
class Comparison:
    labels: tuple[str, ...]
    reference_point: np.ndarray
    hv: tuple[float, ...]
    sizes: tuple[int, ...]
    coverage_matrix: tuple  # [i][j]: share of front j weakly dominated by some member of front i (diagonal 1)
    regions: tuple  # ((f_chat_lo, f_chat_hi, "A" | "B" | ... | "tie" | "A only" | ... | "none"), ...)
    defaults: tuple  # each front's point at its system's default gains (Table 2 for Haidou-1) on its own draws
    systems: tuple = ()  # each front's system ("": Haidou-1)
    objectives: tuple = ("chat", "rmse")

    @property
    def coverage(self) -> tuple[float, float]:
        """(C(A, B), C(B, A)) of the first two fronts."""
        return self.coverage_matrix[0][1], self.coverage_matrix[1][0]

    @property
    def better(self) -> str:
        """The front with the largest hypervolume ("neither" on a tie for the largest)."""
        best = max(self.hv)
        winners = [lab for lab, h in zip(self.labels, self.hv) if h == best]
        return winners[0] if len(winners) == 1 else "neither"

    @property
    def letters(self) -> str:
        return _letters(len(self.labels))


def _letters(n: int) -> str:
    if n > len(string.ascii_uppercase):
        raise ValueError(f"compare: at most {len(string.ascii_uppercase)} fronts, got {n}")
    return string.ascii_uppercase[:n]


def _coverage(A: np.ndarray, B: np.ndarray) -> float:
    """C(A, B): share of B weakly dominated by some member of A."""
    if B.shape[0] == 0:
        return 0.0
    dom = [(np.all(A <= b, axis=1)).any() for b in B]
    return float(np.mean(dom))


def _attain(F: np.ndarray, x: float) -> float:
    m = F[:, 0] <= x
    return float(F[m, 1].min()) if m.any() else np.inf


def _regions(*Fs: np.ndarray) -> list:
    names = _letters(len(Fs))
    xs = np.unique(np.concatenate([F[:, 0] for F in Fs]))
    out: list = []
    for j, x in enumerate(xs):
        hi = xs[j + 1] if j + 1 < len(xs) else np.inf
        a = np.array([_attain(F, x) for F in Fs])
        reach = np.flatnonzero(np.isfinite(a))
        if reach.size == 0:
            who = "none"
        elif reach.size == 1 and len(Fs) > 1:
            who = f"{names[reach[0]]} only"
        else:
            best = np.flatnonzero(a == a.min())
            who = names[best[0]] if best.size == 1 else "tie"
        if out and out[-1][2] == who:
            out[-1] = (out[-1][0], hi, who)
        else:
            out.append((float(x), float(hi), who))
    return out


def compare_fronts(*fronts, ref=None) -> Comparison:
    """Compare two or more fronts (objects, files or study directories); see the module docstring."""
    if len(fronts) < 2:
        raise ValueError(f"compare: needs at least two fronts, got {len(fronts)}")
    frs = [f if isinstance(f, Front) else read_front(f) for f in fronts]
    _letters(len(frs))
    objs = frs[0].objectives
    for f in frs[1:]:
        if f.objectives != objs:
            raise ValueError(f"compare: {frs[0].path} has objectives {', '.join(objs)}, {f.path} has "
                             f"{', '.join(f.objectives)}: fronts of different objectives are not comparable")
    recorded = sorted({f.normalisation for f in frs if f.normalisation and set(objs) & {"chat", "rmse"}})
    if len(recorded) > 1:
        raise ValueError(f"compare: the fronts' objectives are normalised differently ({'; '.join(recorded)}): "
                         f"their f_chat and f_rmse are not comparable")
    if ref is None:
        ref = np.max([f.reference_point for f in frs], axis=0)
    ref = np.asarray(ref, dtype=float)
    if ref.shape != (len(objs),) or not np.isfinite(ref).all():
        raise ValueError(f"--ref: expected {len(objs)} finite numbers (one per objective), got {ref}")
    from arvcas.metrics import objectives as objectives_mod

    for n, r in zip(objs, ref):
        try:
            nonneg = objectives_mod.get(n).nonnegative
        except objectives_mod.ObjectiveError:  # a plugin's objective not loaded: its sign is unknown
            nonneg = False
        if nonneg and r <= 0:
            raise ValueError(f"--ref: the reference point's f_{n} is {r:g}, but f_{n} is never negative: no member "
                             f"can dominate it (give a value > 0)")
    names = [f.controller for f in frs]
    labels = [f"{n} ({f.path.parent.name})" if names.count(n) > 1 else n for n, f in zip(names, frs)]
    labels = [f"{lab} [{k}]" if labels.count(lab) > 1 else lab for lab, k in zip(labels, _letters(len(frs)))]
    return Comparison(
        labels=tuple(labels), reference_point=ref, hv=tuple(hypervolume(f.F, f.G, ref) for f in frs),
        sizes=tuple(f.size for f in frs),
        coverage_matrix=tuple(tuple(_coverage(fi.F, fj.F) for fj in frs) for fi in frs),
        regions=tuple(_regions(*[f.F for f in frs])) if len(objs) == 2 else (), defaults=tuple(f.table2_F for f in frs),
        systems=tuple(f.system for f in frs), objectives=tuple(objs),
    )


def format_comparison(c: Comparison) -> str:
    n = len(c.labels)
    letters = c.letters
    w = max(*(len(x) for x in c.labels), 5)
    fl = ", ".join(f"f_{n}" for n in c.objectives)
    dname = f"{'Table 2' if c.systems and not any(c.systems) else 'defaults'} ({fl})"
    lines = [f"reference point ({fl}) = ({', '.join(f'{x:.6g}' for x in c.reference_point)})",
             f"{'front':<{w}}  {'members':>7}  {'hypervolume':>12}  {dname:>26}"]
    for lab, k, hv, t2 in zip(c.labels, c.sizes, c.hv, c.defaults):
        t2s = f"({', '.join(f'{x:.4g}' for x in t2)})" if np.isfinite(t2).all() else "diverged"
        lines.append(f"{lab:<{w}}  {k:>7}  {hv:>12.6g}  {t2s:>26}")
    lines.append(f"{'larger' if n == 2 else 'largest'} hypervolume: {c.better}")
    if n == 2:
        la, lb = c.labels
        lines.append(f"coverage: {c.coverage[0]:.0%} of {lb}'s front is weakly dominated by {la}'s; "
                     f"{c.coverage[1]:.0%} of {la}'s by {lb}'s")
    else:
        lines.append("coverage: share of each column's front weakly dominated by the row's")
        lines.append(f"{'':<{w}}  " + "  ".join(f"{x:>6}" for x in letters))
        for i, lab in enumerate(c.labels):
            lines.append(f"{letters[i] + ' ' + lab:<{w + 2}}"
                         + "  ".join(f"{'-' if i == j else format(c.coverage_matrix[i][j], '.0%'):>6}"
                                     for j in range(n)))
    names = {"tie": "equal", "none": "neither reaches" if n == 2 else "none reaches"}
    for k, lab in zip(letters, c.labels):
        names[k] = f"{lab} {'lower' if n == 2 else 'lowest'} RMSE"
        names[f"{k} only"] = f"only {lab} reaches"
    if len(c.objectives) != 2:
        return "\n".join(lines)
    fa, fb = (f"f_{n}" for n in c.objectives)
    if fb != "f_rmse":
        names.update({k: f"{lab} {'lower' if n == 2 else 'lowest'} {fb}" for k, lab in zip(letters, c.labels)})
    lines.append(f"where (best {fb} attainable at {fa} <= x):")
    for lo, hi, who in c.regions:
        his = "inf" if np.isinf(hi) else f"{hi:.4g}"
        lines.append(f"  {fa} in [{lo:.4g}, {his}): {names[who]}")
    return "\n".join(lines)
