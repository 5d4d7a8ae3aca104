"""Systems: a vehicle, its thrusters and its arm, described by one data file (docs/system-file.md).

``load_system(name_or_path)`` gives a :class:`System`: its name, its validated :class:`arvcas.system.params.Params`
and the structure that sizes the compiled functions (``n_thrusters``, ``n_joints``). The shipped
systems are the files named in :data:`SHIPPED` under ``arvcas/data/``; ``arvcas systems`` lists them.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from arvcas.system import params as params_mod
from arvcas.system.params import DEFAULT, Params, ParamsError

__all__ = ["System", "SHIPPED", "load_system", "shipped", "resolve", "DEFAULT", "UNSET", "renamed_system", "result_ref"]

SHIPPED = ("haidou1", "bluerov2_heavy_alpha5", "hinsdale_bluerov2_alpha5", "bluerov2", "bluerov2_heavy")


@dataclass(frozen=True)
class System:
    """One described system: ``params`` (numbers, SI) and, through them, its structure."""

    params: Params

    @property
    def name(self) -> str:
        return self.params.structure.name

    @property
    def description(self) -> str:
        return self.params.description

    @property
    def path(self) -> str:
        return self.params.path

    @property
    def layout(self) -> params_mod.Layout:
        return self.params.layout

    @property
    def structure(self):
        return self.params.structure

    @property
    def n_thrusters(self) -> int:
        return self.structure.n_thrusters

    @property
    def n_joints(self) -> int:
        return self.structure.n_joints

    def __repr__(self) -> str:
        return (f"System({self.name!r}: {self.n_thrusters} thrusters, {self.n_joints} joints "
                f"({self.structure.arm} arm), {len(self.params)} parameters, from {self.path})")


def shipped() -> dict[str, Path]:
    """Name -> packaged file of every shipped system (those present in this installation)."""
    root = Path(str(resources.files("arvcas") / "data"))
    return {n: root / f"{n}.toml" for n in SHIPPED if (root / f"{n}.toml").is_file()}


def load_system(name_or_path: str | Path | None = None) -> System:
    """A shipped system by name (``arvcas systems``) or a system file by path (default: :data:`DEFAULT`).

    A one-line :class:`arvcas.system.params.ParamsError` for an unknown name (with the closest shipped one)
    and for every fault of the file (:func:`arvcas.system.params.load`).
    """
    if name_or_path is None:
        name_or_path = DEFAULT
    ships = shipped()
    if isinstance(name_or_path, str) and name_or_path in ships:
        return System(params_mod.load(ships[name_or_path]))
    p = Path(name_or_path)
    if isinstance(name_or_path, str) and p.suffix.lower() not in (".toml",) and not p.exists():
        from arvcas.system.config import closest

        raise ParamsError(f"system {name_or_path!r}: neither a shipped system ({', '.join(ships)}) nor a "
                          f"system file{closest(name_or_path, ships, 0.3)}")
    return System(params_mod.load(p))


class _Unset:
    def __repr__(self) -> str:
        return "UNSET"


UNSET = _Unset()
"""The default of a deprecated ``params=`` keyword: not given (None is a value: the default system)."""


def renamed_system(system, params, where: str):
    """The system of a call that may still use the old keyword ``params=`` (renamed ``system=``; kept one
    release): ``params`` if given, with a :class:`DeprecationWarning` naming the new keyword; both given is a
    one-line :class:`TypeError`."""
    if params is UNSET:
        return system
    if system is not None:
        raise TypeError(f"{where}: system= and params= (its old name) both given; give system= only")
    warnings.warn(f"{where}: the keyword params= is now system= (params= will be removed)", DeprecationWarning,
                  stacklevel=3)
    return params


def resolve(system) -> System:
    """``system`` as a :class:`System`: None (the default system, :data:`DEFAULT`), a name, a path, a System or
    a Params."""
    if isinstance(system, System):
        return system
    if isinstance(system, Params):
        return System(system)
    return load_system(system)


def result_ref(params: Params | None) -> str:
    """How a result file (a front, a Monte Carlo or sweep file) names the system of ``params``: ``""`` for the
    default system (files written before systems were data name it so, and the readers read ``""`` as the
    paper's Haidou-1: its Table 2 gains and Table 3 normalisation), a shipped system's name, or else the
    system file's absolute path (a copy of a shipped file with other numbers is its own system). Decided by
    the system itself, not by how it was asked for: a study naming ``haidou1`` and one naming no system are
    the same study. ``None``: the default system."""
    if params is None:
        return ""
    ships = shipped()
    name = params.structure.name
    if name in ships and params.path is not None and Path(params.path) == ships[name]:
        return "" if name == DEFAULT else name
    return str(Path(params.path).resolve())
