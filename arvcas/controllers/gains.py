"""Controller gain vectors: Table 2 as data (``data/gains.toml``), names, validation.

A gain vector is flat, DOF by DOF (x, y, z, phi, theta, psi), each DOF in Table 2's column order.
"""

from __future__ import annotations

import tomllib
from importlib import resources

import numpy as np

__all__ = [
    "CONTROLLERS", "DOFS", "GainError", "columns", "n_gains", "gain_names", "default_gains",
    "check_controller", "check_gains", "unpack",
]

DOFS = ("x", "y", "z", "phi", "theta", "psi")

# controller -> Table 2 block whose columns (and default values) it uses
CONTROLLERS: dict[str, str] = {
    "proposed": "proposed",  # modified AGSTA + ATD + RESO (section 3)
    "agsta": "agsta",  # original AGSTA with nominal-model compensation (SPEC 5)
    "traditional": "proposed",  # proposed with the zigzagging decreasing law (Fig. 10)
    "implicit": "proposed",  # proposed with the implicit GSTA step (SPEC 5b)
}


class GainError(ValueError):
    """One-line error about a controller name or a gain vector."""


def _table() -> dict:
    with resources.files("arvcas").joinpath("data/gains.toml").open("rb") as f:
        return tomllib.load(f)


_TABLE = _table()


def check_controller(controller: str) -> str:
    if controller not in CONTROLLERS:
        raise GainError(f"controller: unknown '{controller}' (allowed: {', '.join(CONTROLLERS)})")
    return controller


def columns(controller: str) -> list[str]:
    """Table 2's column order for this controller."""
    return list(_TABLE[CONTROLLERS[check_controller(controller)]]["columns"])


def n_gains(controller: str) -> int:
    return 6 * len(columns(controller))


def gain_names(controller: str) -> list[str]:
    """Dotted names of the flat vector: ``x.c, x.mu1, ..., psi.omega``."""
    return [f"{d}.{c}" for d in DOFS for c in columns(controller)]


def default_gains(controller: str) -> np.ndarray:
    """Table 2 as the flat vector (DOF by DOF, x to psi, each in the table's column order)."""
    block = _TABLE[CONTROLLERS[check_controller(controller)]]
    return np.concatenate([np.asarray(block[d], dtype=float) for d in DOFS])


def check_gains(controller: str, gains, h: float | None = None, where: str = "gains") -> np.ndarray:
    """Validate a gain vector (n_gains,) or a batch (n, n_gains); returns a float array.

    Every gain must be finite and > 0 (section 3: arbitrary positive constants); for RESO
    controllers ``h * omega < 2`` (SPEC 5 stability of the explicit observer).
    """
    check_controller(controller)
    g = np.asarray(gains, dtype=float)
    n = n_gains(controller)
    if g.ndim not in (1, 2) or g.shape[-1] != n:
        raise GainError(f"{where}: controller '{controller}' takes {n} gains per set, got shape {g.shape}")
    names = gain_names(controller)
    flat = g.reshape(-1, n)
    bad = ~np.isfinite(flat)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise GainError(f"{where}: set {r}: {names[c]} is not finite ({flat[r, c]})")
    bad = flat <= 0
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise GainError(f"{where}: set {r}: {names[c]} must be > 0, got {flat[r, c]}")
    if h is not None and "omega" in columns(controller):
        idx = [names.index(f"{d}.omega") for d in DOFS]
        hw = h * flat[:, idx]
        if (hw >= 2).any():
            r, c = np.argwhere(hw >= 2)[0]
            raise GainError(
                f"{where}: set {r}: {DOFS[c]}.omega = {flat[r, idx[c]]} gives h*omega = {hw[r, c]:.3g} >= 2: "
                f"the explicit RESO is unstable (need omega < {2 / h:.4g} at h = {h})"
            )
    return g


def unpack(controller: str, gains) -> dict[str, object]:
    """Column name -> 6-vector (one entry per DOF), for any indexable gain vector (NumPy or CasADi)."""
    cols = columns(controller)
    k = len(cols)
    out = {}
    for j, c in enumerate(cols):
        out[c] = [gains[d * k + j] for d in range(6)]
    return out

