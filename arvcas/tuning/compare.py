"""Two fronts side by side: hypervolume against one common reference point, and who dominates where.

* Hypervolume: pymoo's HV indicator for both fronts against the same reference point: by default
  the componentwise maximum of the two studies' reference points (a valid reference for both);
  ``ref`` overrides it. Members that do not dominate the reference point add nothing.
* Coverage (Zitzler's C metric): the fraction of B's members weakly dominated by some member of A,
  and the other way round.
* Where: along f_chat, the attainment curve of each front (the best f_rmse reachable at or below that
  f_chat); the f_chat intervals where one front's curve lies strictly below the other's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from arvcas.tuning.front import Front, read_front
from arvcas.tuning.run import hypervolume

__all__ = ["Comparison", "compare_fronts", "format_comparison"]


@dataclass(frozen=True)
class Comparison:
    labels: tuple[str, str]
    reference_point: np.ndarray
    hv: tuple[float, float]
    sizes: tuple[int, int]
    coverage: tuple[float, float]  # (C(A, B), C(B, A))
    regions: tuple  # ((f_chat_lo, f_chat_hi, "A" | "B" | "tie" | "A only" | "B only"), ...)
    table2: tuple  # (F_A, F_B): each front's Table 2 point on its own draws

    @property
    def better(self) -> str:
        a, b = self.hv
        return self.labels[0] if a > b else self.labels[1] if b > a else "neither"


def _coverage(A: np.ndarray, B: np.ndarray) -> float:
    """C(A, B): share of B weakly dominated by some member of A."""
    if B.shape[0] == 0:
        return 0.0
    dom = [(np.all(A <= b, axis=1)).any() for b in B]
    return float(np.mean(dom))


def _attain(F: np.ndarray, x: float) -> float:
    m = F[:, 0] <= x
    return float(F[m, 1].min()) if m.any() else np.inf


def _regions(A: np.ndarray, B: np.ndarray) -> list:
    xs = np.unique(np.concatenate([A[:, 0], B[:, 0]]))
    out: list = []
    for j, x in enumerate(xs):
        hi = xs[j + 1] if j + 1 < len(xs) else np.inf
        a, b = _attain(A, x), _attain(B, x)
        if np.isinf(a) and np.isinf(b):
            who = "none"
        elif np.isinf(b):
            who = "A only"
        elif np.isinf(a):
            who = "B only"
        else:
            who = "A" if a < b else "B" if b < a else "tie"
        if out and out[-1][2] == who:
            out[-1] = (out[-1][0], hi, who)
        else:
            out.append((float(x), float(hi), who))
    return out


def compare_fronts(a: Front | str, b: Front | str, ref=None) -> Comparison:
    """Compare two fronts (objects, files or study directories); see the module docstring."""
    fa = a if isinstance(a, Front) else read_front(a)
    fb = b if isinstance(b, Front) else read_front(b)
    if ref is None:
        ref = np.maximum(fa.reference_point, fb.reference_point)
    ref = np.asarray(ref, dtype=float)
    if ref.shape != (2,) or not np.isfinite(ref).all():
        raise ValueError(f"--ref: expected two finite numbers, got {ref}")
    la, lb = fa.controller, fb.controller
    if la == lb:
        la, lb = f"{la} ({fa.path.parent.name})", f"{lb} ({fb.path.parent.name})"
    return Comparison(
        labels=(la, lb), reference_point=ref,
        hv=(hypervolume(fa.F, fa.G, ref), hypervolume(fb.F, fb.G, ref)), sizes=(fa.size, fb.size),
        coverage=(_coverage(fa.F, fb.F), _coverage(fb.F, fa.F)), regions=tuple(_regions(fa.F, fb.F)),
        table2=(fa.table2_F, fb.table2_F),
    )


def format_comparison(c: Comparison) -> str:
    la, lb = c.labels
    w = max(len(la), len(lb), 5)
    lines = [f"reference point (f_chat, f_rmse) = ({c.reference_point[0]:.6g}, {c.reference_point[1]:.6g})",
             f"{'front':<{w}}  {'members':>7}  {'hypervolume':>12}  {'Table 2 (f_chat, f_rmse)':>26}"]
    for lab, n, hv, t2 in zip(c.labels, c.sizes, c.hv, c.table2):
        t2s = f"({t2[0]:.4g}, {t2[1]:.4g})" if np.isfinite(t2).all() else "diverged"
        lines.append(f"{lab:<{w}}  {n:>7}  {hv:>12.6g}  {t2s:>26}")
    lines.append(f"larger hypervolume: {c.better}")
    lines.append(f"coverage: {c.coverage[0]:.0%} of {lb}'s front is weakly dominated by {la}'s; "
                 f"{c.coverage[1]:.0%} of {la}'s by {lb}'s")
    names = {"A": f"{la} lower RMSE", "B": f"{lb} lower RMSE", "tie": "equal", "A only": f"only {la} reaches",
             "B only": f"only {lb} reaches", "none": "neither reaches"}
    lines.append("where (best f_rmse attainable at f_chat <= x):")
    for lo, hi, who in c.regions:
        his = "inf" if np.isinf(hi) else f"{hi:.4g}"
        lines.append(f"  f_chat in [{lo:.4g}, {his}): {names[who]}")
    return "\n".join(lines)
