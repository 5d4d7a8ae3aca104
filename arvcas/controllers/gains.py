"""Controller gain vectors: names, defaults (the system's gain table, ``data/gains.toml``), validation.

A gain vector is flat, DOF by DOF (x, y, z, phi, theta, psi), each DOF in the controller's column
order (:attr:`arvcas.controllers.Controller.gains`; for the paper's controllers, Table 2's order).
Every function takes a controller name or a :class:`~arvcas.controllers.Controller` and works for
any registered controller.
"""

from __future__ import annotations

import functools

import numpy as np

from arvcas.controllers.base import DOFS, ControllerError, get, names

__all__ = [
    "DOFS", "GainError", "columns", "n_gains", "gain_names", "gain_units", "default_gains", "controllers",
    "check_controller", "check_gains", "unpack", "upper_limits",
]

GainError = ControllerError


def __getattr__(name: str):
    if name == "CONTROLLERS":  # the registered names, read when asked (a user may register more)
        return names()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _table(path) -> dict:
    """A gain table (a system's ``[defaults] gains``), read once per process."""
    key = str(path)
    t = _TABLES.get(key)
    if t is None:
        from arvcas.system import tomlfile

        t = tomlfile.parse(tomlfile.read_text(path, GainError, "gain table"), key, GainError)
        _TABLES[key] = t
    return t


@functools.lru_cache(maxsize=1)
def _default_system():
    """The default system (:data:`arvcas.system.DEFAULT`), loaded once per process."""
    from arvcas.system import load_system

    return load_system()


_TABLES: dict[str, dict] = {}


def controllers() -> tuple[str, ...]:
    """Names of the registered controllers."""
    return names()


def check_controller(controller) -> str:
    """The controller's name; a one-line :class:`GainError` for an unknown one."""
    return get(controller).name


def columns(controller) -> list[str]:
    """The controller's per-DOF column order."""
    return get(controller).columns()


def n_gains(controller) -> int:
    return 6 * len(columns(controller))


def gain_names(controller) -> list[str]:
    """Dotted names of the flat vector: ``x.c, x.mu1, ..., psi.omega``."""
    return [f"{d}.{c}" for d in DOFS for c in columns(controller)]


def gain_units(controller) -> list[str]:
    """The unit of each entry of the flat vector."""
    units = [g.unit for g in get(controller).gains]
    return [u for _ in DOFS for u in units]


def default_gains(controller, system=None) -> np.ndarray:
    """The system's default gains as the flat vector (DOF by DOF, x to psi, in the column order).

    ``system``: None (the default system), a name, a file, a System or Params: its gain table is the file its
    ``[defaults] gains`` names. A controller may carry its own defaults (``defaults``: column -> 6
    values, or a flat vector) instead of a block of the gain table.
    """
    c = get(controller)
    own = getattr(c, "defaults", None)
    if own is not None:
        g = np.asarray(own, dtype=float).ravel()
        if g.shape != (n_gains(c),):
            raise GainError(f"controller {c.name}: defaults has {g.size} values, expected {n_gains(c)}")
        return g.copy()
    from arvcas.system import resolve

    sysm = _default_system() if system is None else resolve(system)
    path = sysm.params.default("gains")
    if path is None:
        raise GainError(f"system '{sysm.name}' ({sysm.path}) names no gain table ([defaults] gains, "
                        f"docs/system-file.md): give controller {c.name} its gains, or the system a gain table")
    where = str(path)
    block = _table(path).get(c.defaults_block)
    if block is None:
        raise GainError(f"controller {c.name}: the gain table {where} has no block "
                        f"[{c.defaults_block}]; give the controller its own defaults")
    if list(block.get("columns", ())) != c.columns():
        raise GainError(f"{where}: [{c.defaults_block}].columns {block.get('columns')} differ from "
                        f"controller {c.name}'s gain columns {c.columns()}")
    k = len(c.columns())
    for d in DOFS:
        row = block.get(d)
        if not isinstance(row, list) or len(row) != k:
            raise GainError(f"{where}: [{c.defaults_block}].{d}: expected {k} numbers (one per column: "
                            f"{', '.join(c.columns())}), got {row!r}")
        for col, v in zip(c.columns(), row):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise GainError(f"{where}: [{c.defaults_block}].{d}: {col} is {v!r} ({type(v).__name__}); "
                                f"expected a number")
            if not (np.isfinite(v) and v > 0):  # check_gains' rule, here where the file and key are known
                raise GainError(f"{where}: [{c.defaults_block}].{d}: {col} is {v!r}; expected a finite number > 0")
    return np.concatenate([np.asarray(block[d], dtype=float) for d in DOFS])


def upper_limits(controller, h: float) -> np.ndarray:
    """Per entry of the flat vector, the exclusive upper limit stability sets at sampling period h (inf: none)."""
    lim = [g.upper_of_h(h) if g.upper_of_h is not None else np.inf for g in get(controller).gains]
    return np.array([u for _ in DOFS for u in lim], dtype=float)


def check_gains(controller, gains, h: float | None = None, where: str = "gains") -> np.ndarray:
    """Validate a gain vector (n_gains,) or a batch (n, n_gains); returns a float array.

    Every gain must be finite and > 0 (section 3: arbitrary positive constants) and below the limit
    a gain declares for the sampling period ``h`` (e.g. the explicit RESO: ``h * omega < 2``).
    """
    from arvcas.build.calls import real_array

    c = get(controller)
    g = real_array(gains, where, GainError)  # complex, bool, str, masked: refused by name
    n = n_gains(c)
    if g.ndim not in (1, 2) or g.shape[-1] != n:
        raise GainError(f"{where}: controller '{c.name}' takes {n} gains per set, got shape {g.shape}")
    names_ = gain_names(c)
    flat = g.reshape(-1, n)
    bad = ~np.isfinite(flat)
    if bad.any():
        r, k = np.argwhere(bad)[0]
        raise GainError(f"{where}: set {r}: {names_[k]} is not finite ({flat[r, k]})")
    bad = flat <= 0
    if bad.any():
        r, k = np.argwhere(bad)[0]
        raise GainError(f"{where}: set {r}: {names_[k]} must be > 0, got {flat[r, k]}")
    if h is not None:
        lim = upper_limits(c, h)
        bad = flat >= lim
        if bad.any():
            r, k = np.argwhere(bad)[0]
            col = names_[k].split(".", 1)[1]
            gain = next(x for x in c.gains if x.name == col)
            raise GainError(
                f"{where}: set {r}: {names_[k]} = {flat[r, k]} must be < {lim[k]:.4g} at h = {h} "
                f"({gain.description}: h*{col} = {h * flat[r, k]:.3g} >= {h * lim[k]:.3g} is unstable)"
            )
    return g


def unpack(controller, gains) -> dict[str, object]:
    """Column name -> 6-vector (one entry per DOF), for any indexable gain vector (NumPy or CasADi)."""
    cols = columns(controller)
    k = len(cols)
    return {c: [gains[d * k + j] for d in range(6)] for j, c in enumerate(cols)}
