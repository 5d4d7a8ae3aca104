"""Model parameters: load and validate ``data/haidou1.toml`` into an immutable :class:`Params`.

Every physical number of the model lives in that one file, each with its unit and its source. The
file's schema is the dataclasses below (:mod:`arvcas.config`: dimension and rule beside each field);
the loader converts to SI (mm -> m, deg -> rad) and then checks that the numbers describe a physical
vehicle (:func:`check_physical`). ``Params.vector()`` is the runtime input ``p`` of every compiled
function, in the order of ``Params.names()``; model code reads it through :func:`view`, so changing
a number never recompiles.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from arvcas import config
from arvcas.config import ge, gt, quantity

__all__ = ["Params", "ParamsError", "load", "view", "SCHEMA", "UNITS", "default_path", "check_physical"]


class ParamsError(ValueError):
    """A one-line error naming the parameter file and the key at fault."""


UNITS = config.UNITS  # unit string -> (dimension, factor to SI)

# ---- the file's schema (declaration order = the order of Params.vector()) ---------------------------


@dataclass(frozen=True)
class Env:
    rho: float = quantity("density", ge(0))  # rho = 0 is the no-fluid reference case
    g: float = quantity("acceleration", gt(0))
    Cd: float = quantity("1", ge(0))


@dataclass(frozen=True)
class Vehicle:
    m: float = quantity("mass", gt(0))
    buoyancy_excess: float = quantity("mass")
    Ixx: float = quantity("inertia", gt(0))
    Iyy: float = quantity("inertia", gt(0))
    Izz: float = quantity("inertia", gt(0))
    Ixy: float = quantity("inertia")
    Iyz: float = quantity("inertia")
    Ixz: float = quantity("inertia")
    xG: float = quantity("length")
    yG: float = quantity("length")
    zG: float = quantity("length")
    xB: float = quantity("length")
    yB: float = quantity("length")
    zB: float = quantity("length")


_HYDRO = (
    "X_u X_v X_w X_q X_r X_udot X_vdot X_wdot X_qdot X_rdot X_v_absw X_u_absw X_ds "
    "Y_u Y_v Y_r Y_udot Y_vdot Y_rdot Y_v_absv "
    "Z_u Z_w Z_q Z_udot Z_wdot Z_qdot Z_w_absw Z_dsds "
    "K_v K_w K_p K_vdot K_wdot K_pdot K_u_absw "
    "M_u M_w M_q M_udot M_wdot M_qdot M_uw M_w_absw M_dsds M_ds "
    "N_u N_v N_r N_udot N_vdot N_rdot N_v_absv"
).split()
# Table A1's hydrodynamic derivatives, per unit density (the model multiplies by rho)
Hydro = dataclasses.make_dataclass(
    "Hydro", [(k, float, quantity("per_rho")) for k in _HYDRO], frozen=True)


@dataclass(frozen=True)
class Thrusters:
    delta_sL: float = quantity("angle")
    delta_sR: float = quantity("angle")
    x_stn: float = quantity("length")
    y_stn: float = quantity("length")
    z_stn: float = quantity("length")
    x_bow: float = quantity("length")
    y_bow: float = quantity("length")
    x_hB: float = quantity("length")
    x_hS: float = quantity("length")
    u_min: float = quantity("force")
    u_max: float = quantity("force")


@dataclass(frozen=True)
class Mount:
    x: float = quantity("length")
    y: float = quantity("length")
    z: float = quantity("length")


@dataclass(frozen=True)
class Tool:
    length: float = quantity("length", ge(0))


@dataclass(frozen=True)
class Joint:
    """Craig's modified DH row of joint i (a_{i-1}, d_i, alpha_{i-1}) and its limits (Table 1)."""

    a: float = quantity("length")
    d: float = quantity("length")
    alpha: float = quantity("angle")
    qmin: float = quantity("angle")
    qmax: float = quantity("angle")


@dataclass(frozen=True)
class Link:
    mass: float = quantity("mass", gt(0))
    volume: float = quantity("volume", ge(0))
    diameter: float = quantity("length", gt(0))


N_JOINTS = 6
Stow = dataclasses.make_dataclass(
    "Stow", [(f"q{i}", float, quantity("angle")) for i in range(1, N_JOINTS + 1)], frozen=True)
Arm = dataclasses.make_dataclass(
    "Arm",
    [("mount", Mount, config.setting()), ("tool", Tool, config.setting())]
    + [(f"joint{i}", Joint, config.setting()) for i in range(1, N_JOINTS + 1)]
    + [(f"link{i}", Link, config.setting()) for i in range(1, N_JOINTS + 1)]
    + [("stow", Stow, config.setting())],
    frozen=True)


@dataclass(frozen=True)
class Payload:
    mass: float = quantity("mass", ge(0))
    volume: float = quantity("volume", ge(0))


@dataclass(frozen=True)
class ParamFile:
    """The parameter file: every section is required, every entry is { value, unit, source }."""

    env: Env = config.setting()
    vehicle: Vehicle = config.setting()
    hydro: Hydro = config.setting()  # type: ignore[valid-type]
    thrusters: Thrusters = config.setting()
    arm: Arm = config.setting()  # type: ignore[valid-type]
    payload: Payload = config.setting()


def _rule_name(spec: config.Spec) -> str:
    for r in spec.rules:
        if isinstance(r, config.Bound) and r.limit == 0 and r.op in (">", ">="):
            return "pos" if r.op == ">" else "nonneg"
    return "any"


# name -> (dimension, sign rule in {"any", "nonneg", "pos"}), in the order of Params.vector()
SCHEMA: dict[str, tuple[str, str]] = {
    leaf.key: (leaf.spec.dim, _rule_name(leaf.spec)) for leaf in config.leaves(ParamFile)}


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
        """A new ``Params`` with the given SI values replaced (unknown names and bad values refused).

        Each value is checked against its field's rule; the physical checks of :func:`check_physical`
        are not repeated (a study may vary a parameter through a non-physical value on purpose).
        """
        vals = list(self._values)
        srcs = list(self._sources)
        for name, v in mapping.items():
            i = _index(name, "Params.replace")
            vals[i] = config.check_value(ParamFile, name, v, "Params.replace", ParamsError)
            srcs[i] = "replaced at run time"
        return Params(tuple(vals), self._units, tuple(srcs), self.path)


def _index(name: str, where: str) -> int:
    try:
        return _INDEX[name]
    except KeyError:
        raise ParamsError(f"{where}: unknown parameter '{name}'{config.closest(name, SCHEMA)}") from None


_INDEX = {n: i for i, n in enumerate(SCHEMA)}


def load(path: str | Path | None = None) -> Params:
    """Load and validate a parameter file (default: the packaged ``data/haidou1.toml``).

    Raises :class:`ParamsError` with one line naming the file and key for a missing, unreadable,
    non-UTF-8 or malformed file, an unknown or missing key, a wrong unit or type, a non-finite value,
    a broken rule, or numbers that do not describe a physical vehicle (:func:`check_physical`).
    """
    p = Path(path) if path is not None else default_path()
    loaded = config.load_file(ParamFile, p, ParamsError, entries=True)
    flat = config.flatten(loaded.value)
    assert [k for k, _ in flat] == list(SCHEMA)
    values = tuple(float(v) for _, v in flat)
    check_physical(dict(zip(SCHEMA, values)), loaded.where)
    units = tuple(loaded.entries[k][0] for k in SCHEMA)
    sources = tuple(loaded.entries[k][1] for k in SCHEMA)
    return Params(values, units, sources, loaded.where)


# ---- physical validity ------------------------------------------------------------------------------


def _fail(where: str, keys: list[str], msg: str) -> ParamsError:
    return ParamsError(f"{where}: {', '.join(keys)}: {msg}")


def _eig_min(A: np.ndarray) -> float:
    return float(np.linalg.eigvalsh(0.5 * (A + A.T))[0])


def check_physical(values: Mapping[str, float], where: str) -> None:
    """Refuse SI parameter values that do not describe a physical vehicle-manipulator system.

    One-line :class:`ParamsError` naming ``where`` and the keys at fault, for:

    * a vehicle inertia tensor (Ixx..Ixz about the body origin) that is not positive definite, or
      whose principal moments break the triangle inequality (no mass distribution has them);
    * a rigid-body mass matrix M_RB (mass, inertia and centre of gravity) that is not positive definite;
    * a total inertia M = M_RB + M_A (added mass from the hydro ``*dot`` derivatives times rho) whose
      symmetric part is not positive definite: then ``M + M_arm`` may be singular, and the run
      factors it without pivoting (kinetic energy must be positive for every motion);
    * thrust limits u_min >= u_max, joint limits qmin >= qmax, a stowed pose outside its joint limits;
    * a thruster layout whose allocation matrix B_T (Appendix B) is not of rank 6;
    * an arm link of zero length (the cylinder's drag and inertia are along its axis).

    The matrices are the model's own (:mod:`arvcas.model.vehicle`, :mod:`arvcas.model.thrusters`,
    :mod:`arvcas.model.manipulator`), evaluated on numbers, so the check tests what the run will use.
    """
    from arvcas.model import manipulator, thrusters, vehicle  # the model imports this module

    P = view(np.array([values[k] for k in SCHEMA], dtype=float))
    inertia = [f"vehicle.{k}" for k in ("Ixx", "Iyy", "Izz", "Ixy", "Iyz", "Ixz")]
    I_b = np.array(vehicle.I_b(P), dtype=float)
    lam = np.linalg.eigvalsh(I_b)
    if lam[0] <= 0:
        raise _fail(where, inertia, f"the inertia tensor is not positive definite "
                                    f"(eigenvalues {', '.join(f'{x:.6g}' for x in lam)} kg*m^2)")
    if lam[0] + lam[1] < lam[2] * (1 - 1e-12):
        raise _fail(where, inertia, f"the principal moments {', '.join(f'{x:.6g}' for x in lam)} kg*m^2 "
                                    f"break the triangle inequality (no mass distribution has them)")
    rb = ["vehicle.m", *inertia, "vehicle.xG", "vehicle.yG", "vehicle.zG"]
    M_RB = np.array(vehicle.M_RB(P), dtype=float)
    e = _eig_min(M_RB)
    if e <= 0:
        raise _fail(where, rb, f"the rigid-body mass matrix M_RB is not positive definite (smallest "
                               f"eigenvalue {e:.6g}: the inertia about the centre of gravity is not)")
    M = np.array(vehicle.M(P), dtype=float)
    sym = 0.5 * (M + M.T)
    for k in range(1, 7):  # the first leading block that fails names its degree of freedom
        if _eig_min(sym[:k, :k]) <= 0:
            row = [f"hydro.{name}" for i, j, name in vehicle._MA_ENTRIES if i == k - 1]
            raise _fail(where, ["env.rho", *row],
                        f"the inertia M = M_RB + M_A (added mass = -rho * derivative) is not positive "
                        f"definite in DOF {k} (symmetric part's {k}x{k} leading block has eigenvalue "
                        f"{_eig_min(sym[:k, :k]):.6g}): M + M_arm could be singular")
    if not values["thrusters.u_min"] < values["thrusters.u_max"]:
        raise _fail(where, ["thrusters.u_min", "thrusters.u_max"],
                    f"u_min ({values['thrusters.u_min']:g} N) must be < u_max ({values['thrusters.u_max']:g} N)")
    for i in range(1, N_JOINTS + 1):
        lo, hi = values[f"arm.joint{i}.qmin"], values[f"arm.joint{i}.qmax"]
        if not lo < hi:
            raise _fail(where, [f"arm.joint{i}.qmin", f"arm.joint{i}.qmax"],
                        f"qmin ({np.degrees(lo):g} deg) must be < qmax ({np.degrees(hi):g} deg)")
        q = values[f"arm.stow.q{i}"]
        if not lo <= q <= hi:
            raise _fail(where, [f"arm.stow.q{i}"], f"stowed angle {np.degrees(q):g} deg is outside joint {i}'s "
                                                   f"limits [{np.degrees(lo):g}, {np.degrees(hi):g}] deg")
    B = np.array(thrusters.B_T(P), dtype=float)
    sv = np.linalg.svd(B, compute_uv=False)
    rank = int(np.sum(sv > 1e-9 * sv[0]))
    if rank < 6:
        keys = [k for k in SCHEMA if k.startswith("thrusters.") and k not in ("thrusters.u_min", "thrusters.u_max")]
        raise _fail(where, keys, f"the thruster allocation matrix B_T has rank {rank}, not 6 (singular values "
                                 f"{', '.join(f'{x:.3g}' for x in sv)}): the thrusters cannot produce every wrench")
    for i, s in enumerate(manipulator.link_vectors(P), start=1):
        L = float(np.linalg.norm(np.array(s, dtype=float)))
        if L < 1e-9:
            keys = [f"arm.joint{i + 1}.a", f"arm.joint{i + 1}.d"] if i < N_JOINTS else ["arm.tool.length"]
            raise _fail(where, keys, f"link {i} has zero length (diameter {values[f'arm.link{i}.diameter']:g} m, "
                                     f"drag coefficient env.Cd {values['env.Cd']:g}): its drag and inertia "
                                     f"are along its axis")


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
