"""Model parameters: load and validate a system file (``data/<system>.toml``) into an immutable :class:`Params`.

Every physical number of a system lives in its one file, each with its unit and its source. The
file's schema is the dataclasses below (:mod:`arvcas.system.config`: dimension and rule beside each field);
the loader converts to SI (mm -> m, deg -> rad) and then checks that the numbers describe a physical
vehicle (:func:`check_physical`). ``Params.vector()`` is the runtime input ``p`` of every compiled
function, in the order of ``Params.names()``; model code reads it through :func:`view`, so changing
a number never recompiles.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from arvcas.system import config, systemfile, tomlfile

__all__ = ["Params", "ParamsError", "Layout", "load", "view", "layout_for", "default_layout", "SCHEMA", "UNITS",
           "default_path", "check_physical", "check_plausible", "PlausibilityWarning", "DEFAULT"]

DEFAULT = "haidou1"
"""The default system: the shipped system (``data/<DEFAULT>.toml``) that every argument taking a system
uses when given none (re-exported as :data:`arvcas.system.DEFAULT`). The one place that names it."""


class ParamsError(ValueError):
    """A one-line error naming the parameter file and the key at fault."""


UNITS = config.UNITS  # unit string -> (dimension, factor to SI)


def _rule_name(spec: config.Spec) -> str:
    for r in spec.rules:
        if isinstance(r, config.Bound) and r.limit == 0 and r.op in (">", ">="):
            return "pos" if r.op == ">" else "nonneg"
    return "any"


@dataclass(frozen=True, eq=False)
class Layout:
    """The parameter vector of one system structure: names in order, dimension and sign rule of each.

    ``structure`` (:class:`arvcas.system.systemfile.Structure`) is what the model code reads to shape its
    graphs; the numbers are the runtime vector ``p`` in the order of ``names``.
    """

    structure: systemfile.Structure
    schema: type  # the strict file schema (arvcas.system.config dataclasses)
    names: tuple[str, ...]
    dims: tuple[str, ...]
    rules: tuple[str, ...]
    leaf: tuple[str, ...]  # the file key each parameter comes from (a vector's elements share one)
    index: dict = dataclasses.field(repr=False)

    def __len__(self) -> int:
        return len(self.names)

    def schema_dict(self) -> dict[str, tuple[str, str]]:
        return {n: (d, r) for n, d, r in zip(self.names, self.dims, self.rules)}

    def __reduce__(self):  # pickles (to Dask workers) as its structure
        return layout_for, (self.structure,)


_LAYOUTS: dict[systemfile.Structure, Layout] = {}


def layout_for(structure: systemfile.Structure) -> Layout:
    """The (cached) :class:`Layout` of ``structure``."""
    lay = _LAYOUTS.get(structure)
    if lay is not None:
        return lay
    cls = systemfile.schema_for(structure)
    names, dims, rules, leaf = [], [], [], []
    for lf in config.leaves(cls):
        keys = ([f"{lf.key}.{e}" for e in systemfile.element_labels(lf.key, lf.n)]
                if lf.kind == "floats" else [lf.key])
        for k in keys:
            names.append(k)
            dims.append(lf.spec.dim if isinstance(lf.spec.dim, str) else lf.spec.dim[0])
            rules.append(_rule_name(lf.spec))
            leaf.append(lf.key)
    lay = Layout(structure, cls, tuple(names), tuple(dims), tuple(rules), tuple(leaf),
                 {n: i for i, n in enumerate(names)})
    _LAYOUTS[structure] = lay
    return lay


def system_tag(structure) -> str:
    """How a system's structure enters a compile-cache description: `` system=<structure>``, the default
    system (:data:`DEFAULT`) as every other."""
    return f" system={structure.key()}"


def default_path() -> Path:
    """The packaged file of the default system, :data:`DEFAULT`."""
    return Path(str(resources.files("arvcas") / "data" / f"{DEFAULT}.toml"))


@functools.lru_cache(maxsize=1)
def default_layout() -> Layout:
    """The layout of the packaged default system, :data:`DEFAULT` (:func:`default_path`)."""
    return load().layout


def __getattr__(name: str) -> Any:
    if name == "SCHEMA":  # name -> (dimension, sign rule) of the default system, in vector order
        return default_layout().schema_dict()
    raise AttributeError(f"module '{__name__}' has no attribute '{name}'")


@dataclass(frozen=True)
class Params:
    """Immutable, validated model parameters in SI units, in the order of their :class:`Layout`."""

    _values: tuple[float, ...]
    _units: tuple[str, ...]
    _sources: tuple[str, ...]
    path: str
    layout: Layout = dataclasses.field(repr=False, compare=False)
    description: str = dataclasses.field(default="", repr=False, compare=False)
    defaults: tuple[tuple[str, str], ...] = dataclasses.field(default=(), repr=False, compare=False)

    def default(self, what: str) -> Path | None:
        """The file the system names as its default ``what`` ("scenario", "gains"), or None."""
        return next((Path(v) for k, v in self.defaults if k == what), None)

    @property
    def structure(self) -> systemfile.Structure:
        return self.layout.structure

    def names(self) -> list[str]:
        return list(self.layout.names)

    def vector(self) -> np.ndarray:
        """Flat float vector (SI) in the order of :meth:`names`: the ``p`` input of compiled functions."""
        return np.array(self._values, dtype=float)

    def __getitem__(self, name: str) -> float:
        return self._values[self._index(name, self.path)]

    def __iter__(self) -> Iterator[str]:
        return iter(self.layout.names)

    def __len__(self) -> int:
        return len(self.layout.names)

    def unit(self, name: str) -> str:
        """The unit the file gives for ``name`` (the value itself is always SI)."""
        return self._units[self._index(name, self.path)]

    def source(self, name: str) -> str:
        return self._sources[self._index(name, self.path)]

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.layout.names, self._values))

    def replace(self, mapping: Mapping[str, float]) -> "Params":
        """A new ``Params`` with the given SI values replaced (unknown names and bad values refused).

        Each value is checked against its field's rule; the physical checks of :func:`check_physical`
        are not repeated (a study may vary a parameter through a non-physical value on purpose).
        """
        vals = list(self._values)
        srcs = list(self._sources)
        for name, v in mapping.items():
            i = self._index(name, "Params.replace")
            key = self.layout.leaf[i]
            if key == name:
                vals[i] = config.check_value(self.layout.schema, name, v, "Params.replace", ParamsError)
            else:  # an element of a vector entry: a finite number
                if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
                        or not np.isfinite(float(v)):
                    raise ParamsError(f"Params.replace: {name}: expected a finite number, got {v!r}")
                vals[i] = float(v)
            srcs[i] = "replaced at run time"
        return Params(tuple(vals), self._units, tuple(srcs), self.path, self.layout, self.description, self.defaults)

    def instantaneous(self) -> "Params":
        """The same system with thrusters that deliver their (saturated) command at once: the thruster
        dynamics and command maps of the file left out (every other number unchanged, same names)."""
        st = self.structure
        if not st.has_thruster_dynamics:
            return self
        lay = layout_for(st.instantaneous())
        idx = [self.layout.index[n] for n in lay.names]
        pick = lambda seq: tuple(seq[i] for i in idx)  # noqa: E731
        return Params(pick(self._values), pick(self._units), pick(self._sources), self.path, lay, self.description,
                      self.defaults)

    def _index(self, name: str, where: str) -> int:
        try:
            return self.layout.index[name]
        except KeyError:
            raise ParamsError(f"{where}: unknown parameter '{name}'{config.closest(name, self.layout.names)}") \
                from None


def read_doc(path: Path) -> tuple[dict, str]:
    """The parsed system file (a URDF arm converted to the chain form) and its name for messages."""
    where = str(path)
    doc = tomlfile.parse(tomlfile.read_text(path, ParamsError), where, ParamsError)
    arm = doc.get("arm")
    if isinstance(arm, dict) and "urdf" in arm:
        from arvcas.system import urdf

        doc = urdf.convert(doc, path, ParamsError)
    return systemfile.read_tables(doc, path, ParamsError), where


def load(path: str | Path | None = None) -> Params:
    """Load and validate a system file (default: the default system's packaged file, :func:`default_path`).

    Raises :class:`ParamsError` with one line naming the file and key for a missing, unreadable,
    non-UTF-8 or malformed file, an unknown or missing key, a wrong unit or type, a non-finite value,
    a broken rule, or numbers that do not describe a physical system (:func:`check_physical`).
    """
    p = Path(path) if path is not None else default_path()
    doc, where = read_doc(p)
    structure = systemfile.structure_of(doc, where, ParamsError, default_name=_default_name(p))
    lay = layout_for(structure)
    loaded = config.load_doc(lay.schema, systemfile.file_doc(doc), where, ParamsError, entries=True)
    values: list[float] = []
    for key, v in config.flatten(loaded.value):
        values += [x for _, x in systemfile.expand(key, v)]
    assert len(values) == len(lay.names)
    units = tuple(loaded.entries[k][0] for k in lay.leaf)
    sources = tuple(loaded.entries[k][1] for k in lay.leaf)
    check_physical(dict(zip(lay.names, values)), where, lay)
    _warn_implausible(dict(zip(lay.names, values)), where, lay, doc)
    desc = doc.get("system", {}).get("description", "")
    defaults = tuple((k, str(systemfile.rel_path(p, v))) for k, v in doc.get("defaults", {}).items())
    return Params(tuple(values), units, sources, where, lay, desc if isinstance(desc, str) else "", defaults)


def _warn_implausible(values: dict, where: str, lay: Layout, doc: dict) -> None:
    """:func:`check_plausible` on a loaded file: refusals raised, the rest warned (``PlausibilityWarning``)."""
    import warnings

    accept = doc.get("system", {}).get("accept_implausible", False) is True
    for msg in check_plausible(values, where, lay, accept):
        if msg not in _WARNED:  # once per process (a command may load its system twice)
            _WARNED.add(msg)
            warnings.warn(msg, PlausibilityWarning, stacklevel=3)


_WARNED: set[str] = set()


def _default_name(p: Path) -> str:
    stem = p.stem.lower().replace("-", "_")
    return stem if systemfile.NAME_RE.match(stem) else "system"


# ---- physical validity ------------------------------------------------------------------------------


def _fail(where: str, keys: list[str], msg: str) -> ParamsError:
    return ParamsError(f"{where}: {', '.join(keys)}: {msg}")


def _eig_min(A: np.ndarray) -> float:
    return float(np.linalg.eigvalsh(0.5 * (A + A.T))[0])


def check_physical(values: Mapping[str, float], where: str, layout: Layout | None = None) -> None:
    """Refuse SI parameter values that do not describe a physical vehicle-manipulator system.

    One-line :class:`ParamsError` naming ``where`` and the keys at fault, for:

    * a vehicle inertia tensor (Ixx..Ixz about the body origin) that is not positive definite, or
      whose principal moments break the triangle inequality (no mass distribution has them);
    * a rigid-body mass matrix M_RB (mass, inertia and centre of gravity) that is not positive definite;
    * a total inertia M = M_RB + M_A whose symmetric part is not positive definite: then
      ``M + M_arm`` may be singular, and the run factors it without pivoting;
    * thrust limits u_min >= u_max, a thruster direction that is not a unit vector, a thruster layout
      whose allocation matrix B has rank < 6 (less the DOFs of ``[thrusters] unactuated``);
    * joint limits qmin >= qmax, a stowed pose outside its joint limits, a joint axis that is not a unit
      vector, a link inertia that is not positive definite or not physical (triangle inequality);
    * an arm link of zero length with drag (a DH link's cylinder, a chain link's drag segment).

    The matrices are the model's own (:mod:`arvcas.model.vehicle`, :mod:`arvcas.model.thrusters`,
    :mod:`arvcas.model.manipulator`), evaluated on numbers, so the check tests what the run will use.
    """
    from arvcas.model import manipulator, thrusters, vehicle  # the model imports this module

    lay = layout or default_layout()
    st = lay.structure
    P = view(np.array([values[k] for k in lay.names], dtype=float), lay)
    inertia = [f"vehicle.{k}" for k in ("Ixx", "Iyy", "Izz", "Ixy", "Iyz", "Ixz")]
    _check_tensor(np.array(vehicle.I_b(P), dtype=float), where, inertia, "the inertia tensor")
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
            row = [f"hydro.{t.name}" for t in st.hydro if t.dot is not None and t.row == k - 1]
            raise _fail(where, (["env.rho"] if st.hydro_per_rho else []) + row,
                        f"the inertia M = M_RB + M_A is not positive definite in DOF {k} (symmetric part's "
                        f"{k}x{k} leading block has eigenvalue {_eig_min(sym[:k, :k]):.6g}): M + M_arm could "
                        f"be singular")
    for pre in thrusters.limit_prefixes(st):
        lo, hi = values[pre + "u_min"], values[pre + "u_max"]
        if not lo < hi:
            raise _fail(where, [pre + "u_min", pre + "u_max"], f"u_min ({lo:g} N) must be < u_max ({hi:g} N)")
    for name in st.thrusters or ():
        _check_unit(values, f"thrusters.{name}.direction", where, "thrust direction")
    if st.has_thruster_dynamics:
        _check_maps(P, values, where)
    rows = thrusters.actuated(st)  # every DOF, less [thrusters] unactuated
    B = np.array(thrusters.B_T(P), dtype=float)[rows, :]
    sv = np.linalg.svd(B, compute_uv=False)
    rank = int(np.sum(sv > 1e-9 * sv[0]))
    if rank < len(rows):
        keys = ([f"thrusters.{n}.position" for n in st.thrusters] if st.thrusters else
                [k for k in lay.names if k.startswith("thrusters.") and not k.endswith(("u_min", "u_max"))])
        what = "every wrench" if len(rows) == 6 else "a wrench in every actuated degree of freedom"
        hint = ("" if st.unactuated or not st.thrusters else
                " (a vehicle its thrusters cannot pitch says so: [thrusters] unactuated = [\"pitch\"])")
        raise _fail(where, keys, f"the thruster allocation matrix B has rank {rank}, not {len(rows)} (singular "
                                 f"values {', '.join(f'{x:.3g}' for x in sv)}): the thrusters cannot produce "
                                 f"{what}{hint}")
    n = st.n_joints
    for i in range(1, n + 1):
        lo, hi = values[f"arm.joint{i}.qmin"], values[f"arm.joint{i}.qmax"]
        if not lo < hi:
            raise _fail(where, [f"arm.joint{i}.qmin", f"arm.joint{i}.qmax"],
                        f"qmin ({np.degrees(lo):g} deg) must be < qmax ({np.degrees(hi):g} deg)")
        q = values[f"arm.stow.q{i}"]
        if not lo <= q <= hi:
            raise _fail(where, [f"arm.stow.q{i}"], f"stowed angle {np.degrees(q):g} deg is outside joint {i}'s "
                                                   f"limits [{np.degrees(lo):g}, {np.degrees(hi):g}] deg")
    if st.arm == "dh":
        for i, s in enumerate(manipulator.link_vectors(P), start=1):
            L = float(np.linalg.norm(np.array(s, dtype=float)))
            if L < 1e-9:
                keys = [f"arm.joint{i + 1}.a", f"arm.joint{i + 1}.d"] if i < n else ["arm.tool.length"]
                raise _fail(where, keys, f"link {i} has zero length (diameter {values[f'arm.link{i}.diameter']:g} "
                                         f"m, drag coefficient env.Cd {values['env.Cd']:g}): its drag and inertia "
                                         f"are along its axis")
    elif st.arm == "chain":
        for i in range(1, n + 1):
            _check_unit(values, f"arm.joint{i}.axis", where, "joint axis")
            ks = [f"arm.link{i}.inertia.{e}" for e in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")]
            ixx, iyy, izz, ixy, ixz, iyz = (values[k] for k in ks)
            _check_tensor(np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]), where,
                          [f"arm.link{i}.inertia"], f"link {i}'s inertia tensor")
            if st.link_drag[i - 1]:
                a = np.array([values[f"arm.link{i}.drag_from.{c}"] for c in "xyz"])
                b = np.array([values[f"arm.link{i}.drag_to.{c}"] for c in "xyz"])
                if np.linalg.norm(b - a) < 1e-9:
                    raise _fail(where, [f"arm.link{i}.drag_from", f"arm.link{i}.drag_to"],
                                f"link {i}'s drag segment has zero length (drag_diameter "
                                f"{values[f'arm.link{i}.drag_diameter']:g} m): omit the drag entries for a "
                                f"link without drag")


def _check_maps(P, values: Mapping[str, float], where: str) -> None:
    """A quadratic map's command range straddles its dead band; each thruster's thrust limits lie within
    the thrust its map gives over its command range (no allocation may ask for a command outside it)."""
    import casadi as ca

    from arvcas.model import thrusters

    for m in P.s.thruster_maps:
        if m.kind == "quadratic":
            k = f"thrusters.map.{m.name}"
            db, lo, hi = values[f"{k}.dead_band"], values[f"{k}.command_min"], values[f"{k}.command_max"]
            if not (lo < -db and db < hi):
                raise _fail(where, [f"{k}.dead_band"], f"the dead band +-{db:g} covers the command range "
                                                      f"[{lo:g}, {hi:g}]")
    for i, name in enumerate(P.s.thrusters):
        m = P.s.thruster_map(P.s.thruster_dynamics[i].map)
        s_lo, s_hi = thrusters.map_range(P, m)
        ends = ca.DM(ca.vertcat(s_lo, s_hi))
        f_lo, f_hi = (float(x) for x in np.array(ca.DM(thrusters.map_thrust(P, m, ends))).ravel())
        c_lo, c_hi = (float(x) for x in np.array(ca.DM(thrusters.command_of(P, m, ends))).ravel())
        flat_lo, flat_hi = _plateaus(values, m)
        for key, u, ok, end in (("u_min", values[f"thrusters.{name}.u_min"], lambda u: u >= f_lo - 1e-12, (c_lo, f_lo)),
                                ("u_max", values[f"thrusters.{name}.u_max"], lambda u: u <= f_hi + 1e-12, (c_hi, f_hi))):
            flat = flat_lo if key == "u_min" else flat_hi
            if flat is not None and ok(u) and (u <= flat[1] if key == "u_min" else u >= flat[1]):
                raise _fail(where, [f"thrusters.{name}.{key}"],
                            f"{u:g} N lies on the saturation plateau of its map {m.name} ({flat[1]:.6g} N from "
                            f"command {flat[0]:.6g} {m.unit} on): the allocation cannot invert a flat stretch; "
                            f"give a limit {'above' if key == 'u_min' else 'below'} {flat[1]:.6g} N")
            if not ok(u):
                raise _fail(where, [f"thrusters.{name}.{key}"],
                            f"{u:g} N needs a command outside the range of its map {m.name} "
                            f"({end[1]:.6g} N at command {end[0]:.6g} {m.unit}); the map gives "
                            f"[{f_lo:.6g}, {f_hi:.6g}] N")


def _plateaus(values: Mapping[str, float], m) -> tuple:
    """A table map's saturation plateaus, its flat runs of thrust at either end: ((command where the reverse
    plateau ends, its thrust) or None, (command where the forward plateau starts, its thrust) or None)."""
    if m.kind != "table":
        return None, None
    k = f"thrusters.map.{m.name}"
    c = [values[f"{k}.command.{i}"] for i in range(m.n)]
    t = [values[f"{k}.thrust.{i}"] for i in range(m.n)]
    lo = (c[max(i for i in range(m.n) if t[i] == t[0])], t[0]) if t[1] == t[0] else None
    hi = (c[min(i for i in range(m.n) if t[i] == t[-1])], t[-1]) if t[-2] == t[-1] else None
    return lo, hi


def _check_tensor(I: np.ndarray, where: str, keys: list[str], what: str) -> None:
    lam = np.linalg.eigvalsh(0.5 * (I + I.T))
    if lam[0] <= 0:
        raise _fail(where, keys, f"{what} is not positive definite "
                                 f"(eigenvalues {', '.join(f'{x:.6g}' for x in lam)} kg*m^2)")
    if lam[0] + lam[1] < lam[2] * (1 - 1e-12):
        raise _fail(where, keys, f"the principal moments {', '.join(f'{x:.6g}' for x in lam)} kg*m^2 of {what} "
                                 f"break the triangle inequality (no mass distribution has them)")


def _check_unit(values: Mapping[str, float], key: str, where: str, what: str) -> None:
    v = np.array([values[f"{key}.{c}"] for c in "xyz"])
    if abs(np.linalg.norm(v) - 1.0) > 1e-9:
        raise _fail(where, [key], f"the {what} must be a unit vector, its norm is {np.linalg.norm(v):.12g}")


class _View(Mapping[str, Any]):
    __slots__ = ("_p", "layout", "s")

    def __init__(self, p: Any, layout: Layout):
        self._p = p
        self.layout = layout
        self.s = layout.structure  # what the model code reads to shape its graphs

    def __getitem__(self, name: str) -> Any:
        return self._p[self.layout.index[name]]

    def __iter__(self) -> Iterator[str]:
        return iter(self.layout.names)

    def __len__(self) -> int:
        return len(self.layout.names)


def view(p: Any, layout: Layout | None = None) -> Mapping[str, Any]:
    """Name-based access to a parameter vector of any type (CasADi SX/MX/DM, NumPy, Params).

    Model functions take this view, so one implementation builds graphs and evaluates numbers. The
    view's ``s`` is the system's :class:`arvcas.system.systemfile.Structure` (default: Haidou-1's).
    """
    if isinstance(p, Params):
        layout = layout or p.layout
        p = p.vector()
    lay = layout or default_layout()
    if hasattr(p, "shape") and len(p.shape) and p.shape[0] != len(lay):
        raise ParamsError(f"parameter vector has {p.shape[0]} entries, expected {len(lay)} "
                          f"(system {lay.structure.name})")
    return _View(p, lay)


# ---- physical plausibility (docs/system-file.md "Plausibility") -------------------------------------------


class PlausibilityWarning(UserWarning):
    """A system file's number is possible but implausible for its vehicle (docs/system-file.md)."""


_RHO_WATER = 1000.0  # kg/m^3: the scale of a vehicle described without fluid (env.rho = 0)
# (warn above, refuse above) as multiples of the vehicle's own scale
_MASS_RATIO = (1.0, 10.0)  # a link's or the payload's mass (or displaced water) / the vehicle's mass
_LENGTH_RATIO = (10.0, 100.0)  # a distance / the vehicle's size (m / rho)^(1/3)
_THRUST_RATIO = (10.0, 1000.0)  # a thrust limit / the vehicle's weight in air m g
_BUOYANCY = ((0.8, 1.25), (0.1, 10.0))  # buoyancy / weight: warned outside the first, refused outside the second
_CROSSOVER_SPEED = 0.5  # m/s or rad/s: a DOF's damping may turn energy-injecting only above this speed


def check_plausible(values: Mapping[str, float], where: str, layout: Layout, accept: bool = False) -> list[str]:
    """The plausibility rules of docs/system-file.md, against the vehicle's own scale: damping that
    dissipates, buoyancy near the weight, masses, volumes, distances and thrust limits of the size of the
    vehicle. The impossible is refused (one-line :class:`ParamsError` naming the key and the rule) unless
    ``accept`` (the file's ``[system] accept_implausible = true``); the implausible is returned (and, by
    :func:`load`, warned as :class:`PlausibilityWarning`)."""
    st = layout.structure
    rho, g, m = values["env.rho"], values["env.g"], values["vehicle.m"]
    size = (m / (rho if rho > 0 else _RHO_WATER)) ** (1 / 3)
    found: list[tuple[bool, str, str]] = []  # (impossible, key, why)

    def rule(key: str, ratio: float, limits, what: str) -> None:
        if ratio > limits[1]:
            found.append((True, key, f"{what} ({ratio:.3g} times), more than {limits[1]:g} times is not a vehicle"))
        elif ratio > limits[0]:
            found.append((False, key, f"{what} ({ratio:.3g} times), more than {limits[0]:g} times"))

    if rho > 0:
        b = (m + values["vehicle.buoyancy_excess"]) / m if st.buoyancy == "excess" else rho * values["vehicle.volume"] / m
        (wlo, whi), (rlo, rhi) = _BUOYANCY
        key = "vehicle.buoyancy_excess" if st.buoyancy == "excess" else "vehicle.volume"
        if not rlo <= b <= rhi:
            found.append((True, key, f"buoyancy {b:.3g} times the weight (allowed {rlo:g}..{rhi:g}: a unit mix-up?)"))
        elif not wlo <= b <= whi:
            found.append((False, key, f"buoyancy {b:.3g} times the weight (a vehicle is trimmed near 1: "
                                      f"{wlo:g}..{whi:g})"))
    for k in layout.names:
        v = abs(values[k])
        leaf = k.rsplit(".", 1)[-1]
        if (k.startswith("arm.link") and leaf == "mass") or k == "payload.mass":
            rule(k, v / m, _MASS_RATIO, f"{v:g} kg against the vehicle's {m:g} kg")
        elif (k.startswith("arm.link") and leaf == "volume") or k == "payload.volume":
            rule(k, v * (rho if rho > 0 else _RHO_WATER) / m, _MASS_RATIO,
                 f"{v:g} m^3 displaces water of the vehicle's mass")
        elif layout.dims[layout.index[k]] == "length":
            rule(k, v / size, _LENGTH_RATIO, f"{v:g} m against the vehicle's size {size:.3g} m")
        elif k.startswith("thrusters.") and leaf in ("u_min", "u_max"):
            rule(k, v / (m * g), _THRUST_RATIO, f"{v:g} N against the vehicle's weight {m * g:.4g} N")
    found += _damping_rules(values, st)
    refused = [f for f in found if f[0]]
    if refused and not accept:
        _, key, why = refused[0]
        raise ParamsError(f"{where}: {key}: {why}; if this is deliberate, set [system] accept_implausible = true "
                          f"(docs/system-file.md, Plausibility)")
    return [f"{where}: {key}: {why}" for _, key, why in found]


def _damping_rules(values: Mapping[str, float], st) -> list[tuple[bool, str, str]]:
    """Damping must dissipate: the linear damping matrix D (D[row, col] = -coefficient) has a positive
    semidefinite symmetric part (no energy injected at low speed), and a DOF's diagonal damping
    -(linear + quadratic |v|) does not turn negative at every speed (refused) or below
    :data:`_CROSSOVER_SPEED` (warned)."""
    scale = values["env.rho"] if st.hydro_per_rho else 1.0
    D = np.zeros((6, 6))
    quad = {}
    for t in st.hydro:
        c = values[f"hydro.{t.name}"] * scale
        if t.col is None:
            continue
        if not t.factors:
            D[t.row, t.col] += -c
        elif t.row == t.col and t.factors == (f"abs{systemfile.VELOCITIES[t.col]}",):
            quad[t.row] = (t.name, c)
    out = []
    S = 0.5 * (D + D.T)
    eig = np.linalg.eigvalsh(S)
    if eig[0] < -1e-9 * max(1.0, float(np.abs(S).max())):
        keys = [f"hydro.{t.name}" for t in st.hydro if t.col is not None and not t.factors]
        out.append((True, ", ".join(keys) or "hydro", f"the linear damping injects energy (its symmetric part has the "
                                                      f"eigenvalue {eig[0]:.3g}; damping must dissipate: derivatives "
                                                      f"like X_u are <= 0 in Fossen's signs)"))
    for i, (name, q) in quad.items():
        if q <= 0:
            continue
        lcoef = -D[i, i]  # the linear coefficient (<= 0 when dissipative)
        speed = -lcoef / q
        unit = "m/s" if i < 3 else "rad/s"
        if speed <= 0:
            out.append((True, f"hydro.{name}", f"{name} = {q / scale:g} > 0 injects energy at every speed of "
                                               f"{systemfile.VELOCITIES[i]} (damping must dissipate: <= 0 in "
                                               f"Fossen's signs)"))
        elif speed < _CROSSOVER_SPEED:
            out.append((False, f"hydro.{name}", f"{systemfile.VELOCITIES[i]}'s damping injects energy above "
                                                f"{speed:.3g} {unit}"))
    return out
