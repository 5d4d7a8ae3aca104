"""What the two ArduSub study pages share (results/ardusub/render.py, results/ardusub/identified/render.py): the
number format, the improvement factor of a front on ArduSub's defaults, the exports an ArduSub study keeps in its
folder (the knee's and the better member's .param files, compare.txt) with ArduSub's parameter table, and the
Markdown blocks both pages write from them. Each page loads this file by its path (a page is itself loaded by
its path: benchmarks/render_results.py)."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from arvcas.controllers import ardusub
from arvcas.io.ardusub_params import read_param_file

DOFS = ("x", "y", "z", "phi", "theta", "psi")


def g(v, fmt=".3g") -> str:
    return format(float(v), fmt)


def improvement(F: np.ndarray, d: np.ndarray) -> tuple[float, int]:
    """The largest factor by which one front member improves on the point ``d`` in both objectives at once
    (min over the objectives of d / f), and that member: > 1 means the member dominates ``d`` by that factor."""
    k = np.min(d[None, :] / F, axis=1)
    i = int(np.argmax(k))
    return float(k[i]), i


class Exports(NamedTuple):
    """An ArduSub study's folder: its knee's and its better member's parameters, the knee file's header, the
    hypervolumes (compare.txt), ArduSub's parameter table (name -> default, range, description)."""

    knee: dict[str, float]
    better: dict[str, float]
    factor: float  # the better member's improvement on the defaults
    member: int  # the better member
    header: list[str]
    compare: str
    table: dict


def exports(folder: Path, knee: Path, better: Path, front) -> Exports:
    """The exports of the study in ``folder`` whose ardusub front is ``front``; ``better`` must be the member
    of :func:`improvement` on the front's defaults (else: export it again)."""
    factor, member = improvement(front.F, front.table2_F)
    assert f"\n# member: {member}\n" in better.read_text(), f"{better} is not front member {member}; export it again"
    return Exports(knee=read_param_file(knee), better=read_param_file(better), factor=factor, member=member,
                   header=[ln for ln in knee.read_text().splitlines() if ln.startswith("#")],
                   compare=(folder / "compare.txt").read_text().rstrip(), table=ardusub.params()["param"])


def fenced(text: str) -> list[str]:
    """``text`` as a Markdown code block, a blank line either side."""
    return ["", "```", text, "```", ""]


def hypervolumes(compare: str) -> list[str]:
    """compare.txt and the fronts' figure beside it."""
    return fenced(compare) + ["![fronts](fronts.png)", ""]


def beside_defaults(F: np.ndarray, d: np.ndarray) -> str:
    """How far the front ``F`` reaches below the defaults ``d`` in one objective at no more of the other."""
    at_chat, at_rmse = F[F[:, 0] <= d[0]], F[F[:, 1] <= d[1]]
    return ((f"At no more f_chat than the defaults the front's lowest f_rmse is {g(at_chat[:, 1].min())} "
             f"({100 * (1 - at_chat[:, 1].min() / d[1]):.0f} % below the defaults'); " if len(at_chat) else
             "No member has as little f_chat as the defaults; ")
            + (f"at no more f_rmse the lowest f_chat is {g(at_rmse[:, 0].min())} "
               f"({100 * (1 - at_rmse[:, 0].min() / d[0]):.0f} % below)." if len(at_rmse) else
               "no member has as little f_rmse as the defaults."))


def span(F: np.ndarray) -> str:
    """The front's extent in both objectives."""
    return (f"f_chat {g(F[:, 0].min())} to {g(F[:, 0].max())} and f_rmse {g(F[:, 1].min())} to "
            f"{g(F[:, 1].max())}")


def param_range(p: dict) -> str:
    """An ArduSub parameter's range, from its table entry."""
    return f"{g(p['range'][0])} - {g(p['range'][1])}"
