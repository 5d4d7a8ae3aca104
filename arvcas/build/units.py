"""The SI unit of each parameter of a system, for the exports (``export-c``'s params header, the FMU).

A parameter's dimension comes from its system's layout (:attr:`arvcas.system.params.Layout.dims`). The one
dimension that is not a unit is ``per_rho``, the hydrodynamic derivatives: in a file whose derivatives
are ``"per_rho"`` (Haidou-1's Table A1) the number is per unit density and has no single unit; in a
file whose derivatives are ``"SI"`` the number is the SI coefficient of its term, whose unit follows
from the term (:func:`hydro_exponents`: the force or moment over the velocities, accelerations and
angles it multiplies, e.g. ``X_u_absu``: N / (m/s)^2 = kg/m).
"""

from __future__ import annotations

__all__ = ["BASE", "hydro_exponents", "si_exponents", "si_unit", "unit_text"]

BASE = ("kg", "m", "s", "rad")  # the base units the derived units are written in

_FORCE = {"kg": 1, "m": 1, "s": -2}
_MOMENT = {"kg": 1, "m": 2, "s": -2}
_LINEAR, _ANGULAR = "uvw", "pqr"


def _velocity(v: str) -> dict[str, int]:
    return {"m": 1, "s": -1} if v in _LINEAR else {"rad": 1, "s": -1}


def _acceleration(i: int) -> dict[str, int]:
    return {"m": 1, "s": -2} if i < 3 else {"rad": 1, "s": -2}


def _factor(f: str) -> dict[str, int]:
    if f in ("ds", "ds2"):
        return {"rad": 1 if f == "ds" else 2}
    v = f[3:] if f.startswith("abs") else f
    if len(v) != 1 or v not in _LINEAR + _ANGULAR:
        raise ValueError(f"unknown hydrodynamic factor {f!r}")
    return _velocity(v)


def _sub(a: dict[str, int], b: dict[str, int]) -> dict[str, int]:
    out = dict(a)
    for k, e in b.items():
        out[k] = out.get(k, 0) - e
    return {k: e for k, e in out.items() if e}


def hydro_exponents(term) -> dict[str, int]:
    """Base-unit exponents of the SI coefficient of a :class:`arvcas.system.systemfile.HydroTerm`."""
    out = dict(_FORCE if term.row < 3 else _MOMENT)
    if term.dot is not None:
        out = _sub(out, _acceleration(term.dot))
    if term.col is not None:
        out = _sub(out, _velocity((_LINEAR + _ANGULAR)[term.col]))
    for f in term.factors:
        out = _sub(out, _factor(f))
    return out


def unit_text(exps: dict[str, int], mul: str = "*", power: str = "^") -> str:
    """``{"kg": 1, "m": 2, "rad": -2}`` -> ``kg*m^2/rad^2`` (``mul="."``, ``power=""``: ``kg.m2/rad2``)."""
    def part(items):
        return mul.join(k if e == 1 else f"{k}{power}{e}" for k, e in items)

    num = [(k, e) for k in BASE for e in [exps.get(k, 0)] if e > 0]
    den = [(k, -e) for k in BASE for e in [exps.get(k, 0)] if e < 0]
    text = part(num) or "1"
    if den:
        text += "/" + (part(den) if len(den) == 1 else f"({part(den)})")
    return text


def _term(structure, name: str):
    short = name.split(".", 1)[1]
    return next(t for t in structure.hydro if t.name == short)


def si_exponents(params, name: str) -> dict[str, int] | None:
    """Base-unit exponents of an SI hydrodynamic coefficient ``name``; None for any other parameter
    (and for the per-unit-density derivatives of a ``per_rho`` file)."""
    lay = params.layout
    if lay.dims[lay.index[name]] != "per_rho" or lay.structure.hydro_per_rho:
        return None
    return hydro_exponents(_term(lay.structure, name))


def si_unit(params, name: str) -> str:
    """The SI unit of parameter ``name`` as the system files write units (``kg/m^3``, ``rad``, ``per_rho``,
    ``kg/m`` for an SI coefficient ``X_u_absu``)."""
    from arvcas.system.params import UNITS

    exps = si_exponents(params, name)
    if exps is not None:
        return unit_text(exps)
    dim = params.layout.dims[params.layout.index[name]]
    return next(u for u, (d, factor) in UNITS.items() if d == dim and factor == 1.0)
