"""Model parameters: load and validate ``data/haidou1.toml`` into an immutable :class:`Params`.

Every physical number of the model lives in that one file, each with its unit and its source. The
loader converts to SI (mm -> m, deg -> rad). ``Params.vector()`` is the runtime input ``p`` of every
compiled function, in the order of ``Params.names()``; model code reads it through
:func:`view`, so changing a number never recompiles.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from arvcas import tomlfile

__all__ = ["Params", "ParamsError", "load", "view", "SCHEMA", "default_path"]


class ParamsError(ValueError):
    """A one-line error naming the parameter file and the key at fault."""


# unit string -> (dimension, factor to SI)
UNITS: dict[str, tuple[str, float]] = {
    "1": ("dimensionless", 1.0),
    "kg": ("mass", 1.0),
    "kg/m^3": ("density", 1.0),
    "m/s^2": ("acceleration", 1.0),
    "kg*m^2": ("inertia", 1.0),
    "m": ("length", 1.0),
    "mm": ("length", 1e-3),
    "m^3": ("volume", 1.0),
    "deg": ("angle", math.pi / 180.0),
    "rad": ("angle", 1.0),
    "N": ("force", 1.0),
    "per_rho": ("hydro", 1.0),  # hydrodynamic derivative per unit density (SPEC 2)
}

_HYDRO = (
    "X_u X_v X_w X_q X_r X_udot X_vdot X_wdot X_qdot X_rdot X_v_absw X_u_absw X_ds "
    "Y_u Y_v Y_r Y_udot Y_vdot Y_rdot Y_v_absv "
    "Z_u Z_w Z_q Z_udot Z_wdot Z_qdot Z_w_absw Z_dsds "
    "K_v K_w K_p K_vdot K_wdot K_pdot K_u_absw "
    "M_u M_w M_q M_udot M_wdot M_qdot M_uw M_w_absw M_dsds M_ds "
    "N_u N_v N_r N_udot N_vdot N_rdot N_v_absv"
).split()


def _schema() -> dict[str, tuple[str, str]]:
    """name -> (dimension, sign rule); sign rule in {"any", "nonneg", "pos"}."""
    s: dict[str, tuple[str, str]] = {
        "env.rho": ("density", "nonneg"),  # rho = 0 is the no-fluid reference case
        "env.g": ("acceleration", "pos"),
        "env.Cd": ("dimensionless", "nonneg"),
        "vehicle.m": ("mass", "pos"),
        "vehicle.buoyancy_excess": ("mass", "any"),
    }
    for k in ("Ixx", "Iyy", "Izz"):
        s[f"vehicle.{k}"] = ("inertia", "pos")
    for k in ("Ixy", "Iyz", "Ixz"):
        s[f"vehicle.{k}"] = ("inertia", "any")
    for k in ("xG", "yG", "zG", "xB", "yB", "zB"):
        s[f"vehicle.{k}"] = ("length", "any")
    for k in _HYDRO:
        s[f"hydro.{k}"] = ("hydro", "any")
    s["thrusters.delta_sL"] = ("angle", "any")
    s["thrusters.delta_sR"] = ("angle", "any")
    for k in ("x_stn", "y_stn", "z_stn", "x_bow", "y_bow", "x_hB", "x_hS"):
        s[f"thrusters.{k}"] = ("length", "any")
    s["thrusters.u_min"] = ("force", "any")
    s["thrusters.u_max"] = ("force", "any")
    for k in ("x", "y", "z"):
        s[f"arm.mount.{k}"] = ("length", "any")
    s["arm.tool.length"] = ("length", "nonneg")
    for i in range(1, 7):
        s[f"arm.joint{i}.a"] = ("length", "any")
        s[f"arm.joint{i}.d"] = ("length", "any")
        s[f"arm.joint{i}.alpha"] = ("angle", "any")
        s[f"arm.joint{i}.qmin"] = ("angle", "any")
        s[f"arm.joint{i}.qmax"] = ("angle", "any")
    for i in range(1, 7):
        s[f"arm.link{i}.mass"] = ("mass", "pos")
        s[f"arm.link{i}.volume"] = ("volume", "nonneg")
        s[f"arm.link{i}.diameter"] = ("length", "pos")
    for i in range(1, 7):
        s[f"arm.stow.q{i}"] = ("angle", "any")
    s["payload.mass"] = ("mass", "nonneg")
    s["payload.volume"] = ("volume", "nonneg")
    return s


SCHEMA: dict[str, tuple[str, str]] = _schema()


def default_path() -> Path:
    return Path(str(resources.files("arvcas") / "data" / "haidou1.toml"))


@dataclass(frozen=True)
class Params:
    """Immutable, validated model parameters in SI units, ordered as :data:`SCHEMA`."""

    _values: tuple[float, ...]
    _units: tuple[str, ...]
    _sources: tuple[str, ...]
    path: str

    def names(self) -> list[str]:
        return list(SCHEMA)

    def vector(self) -> np.ndarray:
        """Flat float vector (SI) in the order of :meth:`names`: the ``p`` input of compiled functions."""
        return np.array(self._values, dtype=float)

    def __getitem__(self, name: str) -> float:
        return self._values[_index(name, self.path)]

    def __iter__(self) -> Iterator[str]:
        return iter(SCHEMA)

    def __len__(self) -> int:
        return len(SCHEMA)

    def unit(self, name: str) -> str:
        """The unit the file gives for ``name`` (the value itself is always SI)."""
        return self._units[_index(name, self.path)]

    def source(self, name: str) -> str:
        return self._sources[_index(name, self.path)]

    def as_dict(self) -> dict[str, float]:
        return dict(zip(SCHEMA, self._values))

    def replace(self, mapping: Mapping[str, float]) -> "Params":
        """A new ``Params`` with the given SI values replaced (unknown names and bad values refused)."""
        vals = list(self._values)
        srcs = list(self._sources)
        for name, v in mapping.items():
            i = _index(name, "Params.replace")
            vals[i] = _check_value(name, v, "Params.replace")
            srcs[i] = "replaced at run time"
        return Params(tuple(vals), self._units, tuple(srcs), self.path)


def _index(name: str, where: str) -> int:
    try:
        return _INDEX[name]
    except KeyError:
        raise ParamsError(f"{where}: unknown parameter '{name}'{_suggest(name)}") from None


_INDEX = {n: i for i, n in enumerate(SCHEMA)}


def _suggest(name: str) -> str:
    close = difflib.get_close_matches(name, list(SCHEMA), n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _check_value(name: str, v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
        raise ParamsError(f"{where}: {name}: value must be a number, got {type(v).__name__}")
    v = float(v)
    if not math.isfinite(v):
        raise ParamsError(f"{where}: {name}: value must be finite, got {v}")
    rule = SCHEMA[name][1]
    if rule == "pos" and v <= 0:
        raise ParamsError(f"{where}: {name}: value must be > 0, got {v}")
    if rule == "nonneg" and v < 0:
        raise ParamsError(f"{where}: {name}: value must be >= 0, got {v}")
    return v


def _flatten(table: Mapping[str, Any], prefix: str, out: dict[str, Any], where: str) -> None:
    for k, v in table.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict) and "value" not in v:
            _flatten(v, name + ".", out, where)
        else:
            out[name] = v


def load(path: str | Path | None = None) -> Params:
    """Load and validate a parameter file (default: the packaged ``data/haidou1.toml``).

    Raises :class:`ParamsError` with one line naming the file and key for a missing, unreadable,
    non-UTF-8 or malformed file, an unknown or missing key, a wrong unit or type, or a non-finite value.
    """
    p = Path(path) if path is not None else default_path()
    where = str(p)
    doc = tomlfile.parse(tomlfile.read_text(p, ParamsError), where, ParamsError)
    flat: dict[str, Any] = {}
    _flatten(doc, "", flat, where)
    for name in flat:
        if name not in SCHEMA:
            raise ParamsError(f"{where}: unknown key '{name}'{_suggest(name)}")
    missing = [n for n in SCHEMA if n not in flat]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise ParamsError(f"{where}: missing key '{missing[0]}'{more}")
    values, units, sources = [], [], []
    for name, (dim, _rule) in SCHEMA.items():
        entry = flat[name]
        if not isinstance(entry, dict):
            raise ParamsError(f"{where}: {name}: expected a table {{ value, unit, source }}")
        extra = set(entry) - {"value", "unit", "source"}
        if extra:
            raise ParamsError(f"{where}: {name}: unknown field '{sorted(extra)[0]}' (allowed: value, unit, source)")
        for field in ("value", "unit", "source"):
            if field not in entry:
                raise ParamsError(f"{where}: {name}: missing field '{field}'")
        unit = entry["unit"]
        if unit not in UNITS:
            raise ParamsError(f"{where}: {name}: unknown unit '{unit}' (allowed: {', '.join(UNITS)})")
        udim, factor = UNITS[unit]
        if udim != dim:
            allowed = ", ".join(u for u, (d, _) in UNITS.items() if d == dim)
            raise ParamsError(f"{where}: {name}: unit '{unit}' is not a {dim} (allowed: {allowed})")
        if not isinstance(entry["source"], str) or not entry["source"].strip():
            raise ParamsError(f"{where}: {name}: 'source' must be a non-empty string")
        v = _check_value(name, entry["value"], where)
        values.append(v * factor)
        units.append(unit)
        sources.append(entry["source"])
    return Params(tuple(values), tuple(units), tuple(sources), where)


class _View(Mapping[str, Any]):
    __slots__ = ("_p",)

    def __init__(self, p: Any):
        self._p = p

    def __getitem__(self, name: str) -> Any:
        return self._p[_INDEX[name]]

    def __iter__(self) -> Iterator[str]:
        return iter(SCHEMA)

    def __len__(self) -> int:
        return len(SCHEMA)


def view(p: Any) -> Mapping[str, Any]:
    """Name-based access to a parameter vector of any type (CasADi SX/MX/DM, NumPy, Params).

    Model functions take this view, so one implementation builds graphs and evaluates numbers.
    """
    if isinstance(p, Params):
        p = p.vector()
    if hasattr(p, "shape") and len(p.shape) and p.shape[0] != len(SCHEMA):
        raise ParamsError(f"parameter vector has {p.shape[0]} entries, expected {len(SCHEMA)}")
    return _View(p)
