"""Performance indices on stored series: CHAT (eq. 42), RMSE (eq. 43), and the docs/model.md §7 objectives.

NumPy only; inputs are the series a run stores at the controller samples ``t_k = k h``
(``h = 0.1 s``), whole run. With a run of length ``t_f`` there are ``N = t_f / h`` sampling
intervals (``N = 1000`` for 100 s), and the samples are ``k = 0, 1, ..., N`` (paper, after
eq. 43: ``f(t_k) = f_k``, ``k = 0, 1, 2, ..., N``):

- CHAT uses all ``N + 1`` commands ``tau_v,0 ... tau_v,N`` (``N`` differences);
- RMSE sums ``k = 0 ... N - 1``, i.e. the ``N`` errors ``e_0 ... e_{N-1}`` (the final sample
  ``e_N`` is outside eq. 43's sum).

The paper's Table 3 lives in ``data/table3.toml`` (the one source of those numbers).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np

__all__ = ["chat", "rmse", "Table3", "table3", "normalised_objectives", "reference_values", "defaults_name",
           "norm_name", "DOFS"]

DOFS = ("x", "y", "z", "phi", "theta", "psi")


def _series(a, name, min_rows):
    a = np.asarray(a, dtype=float)
    if a.ndim not in (1, 2) or a.shape[0] < min_rows:
        raise ValueError(f"{name}: expected shape (rows, dofs) with rows >= {min_rows}, got {a.shape}")
    return a


def chat(tau):
    """CHAT, eq. (42): ``1/N sum_{k=0}^{N-1} |tau_{k+1} - tau_k|`` per DOF.

    Args:
        tau: commanded ``tau_v`` (body frame; N for X, Y, Z and N m for K, M, N) at the
            controller samples ``k = 0 ... N`` of the whole run, shape ``(N + 1, 6)`` (or
            ``(N + 1,)`` for one DOF). Commanded means before the thrusters' saturation.

    Returns:
        Mean absolute change per sample, shape ``(6,)`` (or a scalar), units of ``tau``.
    """
    tau = _series(tau, "chat: tau", 2)
    return np.mean(np.abs(np.diff(tau, axis=0)), axis=0)


def rmse(e):
    """RMSE, eq. (43): ``sqrt(1/N sum_{k=0}^{N-1} e_k^2)`` per DOF.

    Args:
        e: pose error ``e = eta_true - y1`` (m, rad; in {n}) at the controller samples
            ``k = 0 ... N - 1`` of the whole run, shape ``(N, 6)`` (or ``(N,)``). From a stored
            series of ``N + 1`` samples pass ``e[:-1]`` to follow eq. (43) literally.

    Returns:
        Root mean square per DOF, shape ``(6,)`` (or a scalar), units of ``e``.
    """
    e = _series(e, "rmse: e", 1)
    return np.sqrt(np.mean(e**2, axis=0))


@dataclass(frozen=True)
class Table3:
    """The paper's Table 3, per DOF in the order of :data:`DOFS` (read-only arrays of shape (6,))."""

    chat_agsta: np.ndarray
    chat_proposed: np.ndarray
    rmse_agsta: np.ndarray
    rmse_proposed: np.ndarray


def _row(section, key, where):
    v = section.get(key)
    if not isinstance(v, list) or len(v) != len(DOFS):
        raise ValueError(f"{where}.{key}: expected a list of {len(DOFS)} numbers")
    a = np.array(v, dtype=float)
    if not all(math.isfinite(x) and x > 0 for x in a):
        raise ValueError(f"{where}.{key}: every value must be finite and positive")
    a.setflags(write=False)
    return a


@lru_cache(maxsize=1)
def table3() -> Table3:
    """Load and validate ``data/table3.toml`` (unknown keys are rejected)."""
    where = "arvcas/data/table3.toml"
    with resources.files("arvcas").joinpath("data/table3.toml").open("rb") as f:
        d = tomllib.load(f)
    if set(d) != {"dofs", "chat", "rmse"}:
        raise ValueError(f"{where}: expected keys dofs, chat, rmse; got {sorted(d)}")
    if tuple(d["dofs"]) != DOFS:
        raise ValueError(f"{where}: dofs must be {list(DOFS)}, got {d['dofs']}")
    for sec in ("chat", "rmse"):
        if set(d[sec]) != {"unit", "source", "agsta", "proposed"}:
            raise ValueError(
                f"{where}: [{sec}] expected keys unit, source, agsta, proposed; got {sorted(d[sec])}"
            )
    return Table3(
        chat_agsta=_row(d["chat"], "agsta", f"{where} [chat]"),
        chat_proposed=_row(d["chat"], "proposed", f"{where} [chat]"),
        rmse_agsta=_row(d["rmse"], "agsta", f"{where} [rmse]"),
        rmse_proposed=_row(d["rmse"], "proposed", f"{where} [rmse]"),
    )


def normalised_objectives(chat_values, rmse_values, ref=None, held=None):
    """The two tuning objectives of docs/model.md §7: ``(f_chat, f_rmse)``.

    ``f_chat = mean_i chat_i / CHAT_AGSTA,i`` and ``f_rmse = mean_i rmse_i / RMSE_AGSTA,i`` over
    the 6 DOF, normalised by the paper's Table 3 AGSTA values so that linear and angular DOFs
    weigh alike. The paper's AGSTA run itself scores ``(1, 1)``.

    Args:
        chat_values: per-DOF CHAT, shape ``(6,)`` (from :func:`chat`).
        rmse_values: per-DOF RMSE, shape ``(6,)`` (from :func:`rmse`).
        ref: ``(chat_ref, rmse_ref)`` per DOF to normalise by instead of Table 3's AGSTA (another
            system: its AGSTA at its default gains on the study's first draw, arvcas.tuning.run).
        held: the DOFs the task holds (6 booleans; None: all): ``f_rmse`` is the mean over those only
            (without a position sensor x and y are not held, docs/sensors.md).
    """
    c = np.asarray(chat_values, dtype=float)
    r = np.asarray(rmse_values, dtype=float)
    if c.shape != (len(DOFS),) or r.shape != (len(DOFS),):
        raise ValueError(
            f"normalised_objectives: expected two shape-(6,) arrays, got {c.shape} and {r.shape}"
        )
    if held is not None and not all(held):
        c_ref, r_ref = reference_values(ref)
        k = np.asarray(held, dtype=bool)
        return float(np.mean(c / c_ref)), float(np.mean(r[k] / np.asarray(r_ref)[k]))
    if ref is not None:
        return float(np.mean(c / np.asarray(ref[0]))), float(np.mean(r / np.asarray(ref[1])))
    t = table3()
    return float(np.mean(c / t.chat_agsta)), float(np.mean(r / t.rmse_agsta))


def reference_values(ref=None) -> tuple[np.ndarray, np.ndarray]:
    """Per-DOF ``(chat_ref, rmse_ref)`` the objectives divide by: ``ref`` (another system's AGSTA at its
    default gains), else the paper's Table 3 AGSTA values (Haidou-1)."""
    if ref is not None:
        return np.asarray(ref[0], dtype=float), np.asarray(ref[1], dtype=float)
    t = table3()
    return t.chat_agsta, t.rmse_agsta


# How outputs name the default gains and the objectives' normalisation: the paper's tables for Haidou-1
# only (``system`` "" is Haidou-1, as fronts and result files record it), the system's own otherwise.


def defaults_name(system: str = "") -> str:
    """``"Table 2 gains"`` for Haidou-1, ``"default gains"`` for another system (its gains file)."""
    return "Table 2 gains" if not system else "default gains"


def norm_name(system: str = "") -> str:
    """What the objectives divide by: ``"the paper's AGSTA value"`` for Haidou-1 (Table 3), else
    ``"AGSTA's value at the default gains"`` (docs/model.md §8)."""
    return "the paper's AGSTA value" if not system else "AGSTA's value at the default gains"
