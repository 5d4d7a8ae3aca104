"""Strict configuration loading: TOML tables -> nested frozen dataclasses, units and rules per field.

One loader for the parameter file (``data/haidou1.toml``), the scenario file (``data/scenario.toml``)
and study files (``studies/*.toml``), in the manner of Drake's strict YAML-to-struct loading: the
dataclass is the schema. Each field declares

* its type: ``float``, ``int``, ``str``, ``bool``, ``tuple[float, ...]`` (length ``n``, or from
  ``tuple[float, float]``), ``tuple[str, ...]``, a nested dataclass (a TOML table), a tuple of
  dataclasses (an array of tables ``[[x]]``), ``dict[str, X]`` (free keys, checked by the caller) or
  ``X | None`` (optional, absent = None);
* with :func:`quantity`, its physical dimension (a key of :data:`DIMENSIONS`; ``"length or angle"``
  for one number that serves both kinds of component; a tuple of dimensions, one per element, for
  vectors);
* its rules (:func:`gt`, :func:`ge`, :func:`lt`, :func:`le`, :class:`Choices`, :class:`Unique`,
  :class:`Count`, :class:`Equals`), checked on the SI value;
* a dataclass may add cross-field rules as a method ``_config_check(self, given)`` raising
  :class:`Invalid` (``given``: the keys the file wrote).

Two file styles. *Entry* files (parameters, scenario) write every leaf as
``key = { value = ..., unit = "...", source = "..." }``; the unit is checked against the field's
dimension and converted to SI with :data:`UNITS`. A vector's unit is one unit for all elements, one
per element (``"m,m,m,deg,deg,deg"``) or two for its halves (``"m/s,rad/s"``); a number that serves
two dimensions takes ``"m or rad"``. ``"SI"`` is accepted for any dimension (factor 1: what
:meth:`arvcas.sim.scenario.ScenarioConfig.to_toml` writes). *Plain* files (studies) write bare values;
a field may declare the unit its number is in (``unit="deg"``), converted the same way.

Every fault is one line naming the file and the dotted key: an unknown key (with the closest valid
name), a missing key or section, a wrong type, a unit that is unknown or of the wrong dimension (with
the allowed ones), a non-finite number, a broken rule.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import numbers
import re
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Generic, Mapping, TypeVar

from arvcas.system import tomlfile

__all__ = [
    "UNITS", "STANDARD_GRAVITY", "DIMENSIONS", "SI", "MEMORY_CAP_BYTES", "Invalid", "Bound", "gt", "ge", "lt", "le",
    "Choices", "Unique", "Count", "Equals", "Spec", "quantity", "setting", "Loaded", "Leaf",
    "load_file", "load_text", "load_doc", "leaves", "flatten", "check_value", "closest", "si_unit",
    "format_bytes", "check_memory",
]

T = TypeVar("T")

STANDARD_GRAVITY = 9.80665  # m/s^2, exact by definition (3rd CGPM, 1901): kgf, mG, depth from pressure

# unit string -> (dimension, factor to SI). For each dimension the first unit of factor 1 is its SI name.
UNITS: dict[str, tuple[str, float]] = {
    "1": ("1", 1.0),
    "m": ("length", 1.0),
    "mm": ("length", 1e-3),
    "rad": ("angle", 1.0),
    "deg": ("angle", math.pi / 180.0),
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "kg": ("mass", 1.0),
    "N": ("force", 1.0),
    "N*m": ("torque", 1.0),
    "kg/m^3": ("density", 1.0),
    "m/s^2": ("acceleration", 1.0),
    "kg*m^2": ("inertia", 1.0),
    "m^3": ("volume", 1.0),
    "m/s": ("velocity", 1.0),
    "rad/s": ("angular_velocity", 1.0),
    "deg/s": ("angular_velocity", math.pi / 180.0),
    "m^2": ("length^2", 1.0),
    "rad^2": ("angle^2", 1.0),
    "deg^2": ("angle^2", (math.pi / 180.0) ** 2),
    "(m/s)^2": ("velocity^2", 1.0),
    "(rad/s)^2": ("angular_velocity^2", 1.0),
    "(deg/s)^2": ("angular_velocity^2", (math.pi / 180.0) ** 2),
    # thrusters (docs/system-file.md): an autopilot's command and the thrust it gives
    "kgf": ("force", STANDARD_GRAVITY),  # kilogram-force (Blue Robotics' T200 tables), exact by definition
    "us": ("pwm", 1.0),  # an ESC's PWM pulse width in microseconds: a command, kept in its own unit
    "us/s": ("pwm_rate", 1.0),
    "1/s": ("rate", 1.0),  # a normalised command per second
    "rad/s^2": ("angular_acceleration", 1.0),
    "N*s^2/rad^2": ("rotor_constant", 1.0),  # thrust per squared rotor speed (uuv_simulator's rotorConstant)
    # hydrodynamic derivative per unit density: the model's coefficient is rho * value (paper App. A)
    "per_rho": ("per_rho", 1.0),
    # an autopilot's logs (docs/logs.md): pressure for depth, MAVLink's milli-units
    "Pa": ("pressure", 1.0),
    "hPa": ("pressure", 100.0),
    "mbar": ("pressure", 100.0),
    "kPa": ("pressure", 1000.0),
    "mrad/s": ("angular_velocity", 1e-3),
    "mG": ("acceleration", 1e-3 * STANDARD_GRAVITY),
    "cm": ("length", 1e-2),
    "cm/s": ("velocity", 1e-2),
    "mm/s": ("velocity", 1e-3),
}
DIMENSIONS: tuple[str, ...] = tuple(dict.fromkeys(d for d, _ in UNITS.values()))
SI = "SI"  # accepted for every dimension, factor 1
ANY_LENGTH = -1  # quantity(n=ANY_LENGTH): a vector whose length the caller checks (e.g. one per joint)

# The largest table a scenario or a study may ask a run to hold, 2 GB: a request whose estimate is
# larger is refused before any work. A run's estimate is its time table for its system
# (arvcas.sim.schedule.table_bytes: 8.6 MB for Haidou-1 in the 100 s paper run at h_plant = 0.05 s, 36 MB at
# 0.01 s), a study's the per-draw metrics of one generation (arvcas.tuning.study).
MEMORY_CAP_BYTES = 2_000_000_000


class Invalid(Exception):
    """Raised by a dataclass's ``_config_check``: ``key`` (relative to the table, or None) and a message."""

    def __init__(self, key: str | None, message: str):
        super().__init__(message)
        self.key = key
        self.message = message


# ---- rules ----------------------------------------------------------------------------------------

_OPS = {">": lambda x, y: x > y, ">=": lambda x, y: x >= y, "<": lambda x, y: x < y, "<=": lambda x, y: x <= y}


@dataclass(frozen=True)
class Bound:
    """``value op limit`` on the SI value (``why`` is appended to the message)."""

    op: str
    limit: float
    why: str = ""

    def problem(self, x: float, dim: str | None) -> str | None:
        if _OPS[self.op](x, self.limit):
            return None
        lim = f"{self.limit:g}"
        if self.limit != 0 and dim not in (None, "1"):
            lim += f" {si_unit(dim)}"
        return f"must be {self.op} {lim}" + (f" ({self.why})" if self.why else "")


def gt(limit: float, why: str = "") -> Bound:
    return Bound(">", limit, why)


def ge(limit: float, why: str = "") -> Bound:
    return Bound(">=", limit, why)


def lt(limit: float, why: str = "") -> Bound:
    return Bound("<", limit, why)


def le(limit: float, why: str = "") -> Bound:
    return Bound("<=", limit, why)


@dataclass(frozen=True)
class Choices:
    """A string (or each string of a list) is one of ``allowed`` (a tuple, or a function giving one when
    a file is read: e.g. the controllers registered by then); ``noun`` names what it is."""

    allowed: tuple[str, ...] | Callable[[], tuple[str, ...]]
    noun: str = "value"

    @property
    def options(self) -> tuple[str, ...]:
        return tuple(self.allowed() if callable(self.allowed) else self.allowed)


@dataclass(frozen=True)
class Unique:
    """No string listed twice."""


@dataclass(frozen=True)
class Count:
    """The number of elements of a list or of an array of tables is within [lo, hi]."""

    lo: int = 1
    hi: int | None = None
    why: str = ""


@dataclass(frozen=True)
class Equals:
    """The value is exactly ``value`` (a fixed choice the file must state)."""

    value: Any
    why: str = ""


# ---- field declarations -------------------------------------------------------------------------


@dataclass(frozen=True)
class Spec:
    dim: str | tuple[str, ...] | None = None
    rules: tuple = ()
    unit: str | None = None  # plain files: the unit of the number written (default: SI)
    key: str | None = None  # the file's key when it differs from the field name
    n: int | None = None  # length of a tuple[float, ...]
    required: bool = False  # required in the file although the dataclass has a default
    scalar_ok: bool = False  # a tuple[str, ...] may be written as one string
    per: str | None = None  # a quantity per step, per sample...: its unit may end in " per <per>"


_META = "arvcas.system.config"


def _field(spec: Spec, default: Any, default_factory: Any) -> Any:
    kw: dict[str, Any] = {"metadata": {_META: spec}}
    if default is not dataclasses.MISSING:
        kw["default"] = default
    if default_factory is not dataclasses.MISSING:
        kw["default_factory"] = default_factory
    return dataclasses.field(**kw)


def quantity(dim: str | tuple[str, ...], *rules: Any, default: Any = dataclasses.MISSING,
             default_factory: Any = dataclasses.MISSING, unit: str | None = None, key: str | None = None,
             n: int | None = None, required: bool = False, per: str | None = None) -> Any:
    """A physical number (or vector) of dimension ``dim``; ``rules`` apply to its SI value.

    ``per``: the value is an amount per ``per`` (e.g. ``"step"``), and its unit string may say so
    (``"m^2 or rad^2 per step"``); the qualifier does not change the factor."""
    dims = dim if isinstance(dim, tuple) else (dim,)
    for d in dims:
        for part in d.split(" or "):
            if part not in DIMENSIONS:
                raise ValueError(f"config: unknown dimension {part!r} (known: {', '.join(DIMENSIONS)})")
    if isinstance(dim, tuple):
        if n is not None and n != len(dim):
            raise ValueError(f"config: {len(dim)} dimensions for a vector of {n}")
        n = len(dim)
    if unit is not None:
        _factor_of(unit, dims[0] if len(dims) == 1 else None)
    return _field(Spec(dim=dim, rules=tuple(rules), unit=unit, key=key, n=n, required=required, per=per),
                  default, default_factory)


def setting(*rules: Any, default: Any = dataclasses.MISSING, default_factory: Any = dataclasses.MISSING,
            key: str | None = None, required: bool = False, scalar_ok: bool = False) -> Any:
    """A non-physical value (int, str, bool, section, list of tables) with its rules."""
    return _field(Spec(rules=tuple(rules), key=key, required=required, scalar_ok=scalar_ok),
                  default, default_factory)


def _factor_of(unit: str, dim: str | None) -> float:
    if unit not in UNITS:
        raise ValueError(f"config: unknown unit {unit!r}")
    udim, f = UNITS[unit]
    if dim is not None and udim != dim:
        raise ValueError(f"config: unit {unit!r} is not a {dim}")
    return f


def si_unit(dim: str) -> str:
    """The SI unit string of a dimension (``"length or angle"`` -> ``"m or rad"``)."""
    return " or ".join(next(u for u, (d, f) in UNITS.items() if d == part and f == 1.0) for part in dim.split(" or "))


def _a(dim: str) -> str:
    return ("an " if dim[0] in "aeiou" else "a ") + dim


def _allowed(dim: str) -> list[str]:
    parts = dim.split(" or ")
    if len(parts) == 1:
        return [u for u, (d, _) in UNITS.items() if d == dim]
    out = [""]
    for part in parts:
        out = [f"{a} or {u}" if a else u for a in out for u, (d, _) in UNITS.items() if d == part]
    return [u for u in out if len({UNITS[p][1] for p in u.split(" or ")}) == 1]


# ---- the schema of a dataclass --------------------------------------------------------------------


@dataclass(frozen=True)
class _F:
    name: str
    key: str
    kind: str  # float floats int bool str strs section tables map
    spec: Spec
    optional: bool
    has_default: bool
    sub: Any = None  # dataclass of a section / tables; value _F of a map
    n: int | None = None


_CACHE: dict[type, tuple[_F, ...]] = {}


def _kind(tp: Any, spec: Spec, where: str) -> tuple[str, bool, Any, int | None]:
    optional = False
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) != 1:
            raise TypeError(f"config: {where}: unsupported type {tp}")
        tp, optional = args[0], True
        origin = typing.get_origin(tp)
    if tp is float:
        return "float", optional, None, None
    if tp is bool:
        return "bool", optional, None, None
    if tp is int:
        return "int", optional, None, None
    if tp is str:
        return "str", optional, None, None
    if dataclasses.is_dataclass(tp):
        return "section", optional, tp, None
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            el = args[0]
            if el is float:
                return "floats", optional, None, spec.n
            if el is str:
                return "strs", optional, None, None
            if dataclasses.is_dataclass(el):
                return "tables", optional, el, None
        elif args and all(a is float for a in args):
            return "floats", optional, None, len(args)
    if origin is dict:
        k, v = typing.get_args(tp)
        if k is str:
            vk, _, vsub, vn = _kind(v, spec, where)
            return "map", optional, _F("*", "*", vk, spec, False, False, vsub, vn), None
    raise TypeError(f"config: {where}: unsupported type {tp}")


def _fields(cls: type) -> tuple[_F, ...]:
    out = _CACHE.get(cls)
    if out is not None:
        return out
    hints = typing.get_type_hints(cls)
    fs = []
    for f in dataclasses.fields(cls):
        spec = f.metadata.get(_META)
        if spec is None:
            continue  # not part of the file (e.g. text, path)
        kind, optional, sub, n = _kind(hints[f.name], spec, f"{cls.__name__}.{f.name}")
        if kind == "floats" and n is None:
            raise TypeError(f"config: {cls.__name__}.{f.name}: a vector needs its length (n=...)")
        if kind in ("float", "floats") and spec.dim is None:
            raise TypeError(f"config: {cls.__name__}.{f.name}: a number needs its dimension (quantity(...))")
        has_default = f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
        fs.append(_F(f.name, spec.key or f.name, kind, spec, optional, has_default, sub, n))
    out = tuple(fs)
    _CACHE[cls] = out
    return out


@dataclass(frozen=True)
class Leaf:
    """One value of a schema: its dotted key in the file, field path in the dataclasses, and declaration."""

    key: str
    attrs: tuple[str, ...]
    kind: str
    spec: Spec
    n: int | None


def leaves(cls: type, prefix: str = "", attrs: tuple[str, ...] = ()) -> list[Leaf]:
    """Every leaf of ``cls`` (sections expanded, in declaration order)."""
    if not prefix and not attrs:
        cached = _LEAVES.get(cls)
        if cached is None:
            cached = _LEAVES[cls] = tuple(_leaves(cls, "", ()))
        return list(cached)
    return _leaves(cls, prefix, attrs)


_LEAVES: dict[type, tuple[Leaf, ...]] = {}


def _leaves(cls: type, prefix: str, attrs: tuple[str, ...]) -> list[Leaf]:
    out: list[Leaf] = []
    for f in _fields(cls):
        key = f"{prefix}{f.key}"
        if f.kind == "section":
            out += _leaves(f.sub, key + ".", attrs + (f.name,))
        else:
            out.append(Leaf(key, attrs + (f.name,), f.kind, f.spec, f.n))
    return out


def _paths(cls: type, prefix: str = "") -> list[str]:
    out: list[str] = []
    for f in _fields(cls):
        key = f"{prefix}{f.key}"
        out.append(key)
        if f.kind in ("section", "tables"):
            out += _paths(f.sub, key + ".")
    return out


def flatten(obj: Any) -> list[tuple[str, Any]]:
    """(dotted key, value) of every leaf of a loaded instance, in declaration order."""
    out = []
    for leaf in leaves(type(obj)):
        v = obj
        for a in leaf.attrs:
            v = getattr(v, a)
        out.append((leaf.key, v))
    return out


def closest(name: str, choices, cutoff: float = 0.6) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``choices``, or ``""``."""
    close = difflib.get_close_matches(name, list(choices), n=1, cutoff=cutoff)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _tname(v: Any) -> str:
    return {bool: "boolean", int: "integer", float: "number", str: "string", list: "array",
            dict: "table"}.get(type(v), type(v).__name__)


def _got(v: Any) -> str:
    if isinstance(v, list):
        return f"an array of {len(v)}"
    if isinstance(v, dict):
        return "a table"
    return f"{_tname(v)} {v!r}"


# ---- loading --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Loaded(Generic[T]):
    """A loaded file: the dataclass ``value``; for entry files the (unit, source) of every dotted key."""

    value: T
    entries: dict[str, tuple[str, str]]
    where: str


class _Ctx:
    def __init__(self, root: type, where: str, error: type[Exception], entry_style: bool):
        self.root, self.where, self.error, self.entry_style = root, where, error, entry_style
        self.entries: dict[str, tuple[str, str]] = {}
        self._paths: list[str] | None = None

    def fail(self, key: str, msg: str) -> Exception:
        return self.error(f"{self.where}: {key}: {msg}" if key else f"{self.where}: {msg}")

    def paths(self) -> list[str]:
        if self._paths is None:
            self._paths = _paths(self.root)
        return self._paths


def load_file(cls: type[T], path: str | Path, error: type[Exception], *, entries: bool = False,
              what: str = "file") -> Loaded[T]:
    """Read (:func:`arvcas.system.tomlfile.read_text`), parse and load a TOML file into ``cls``."""
    p = Path(path)
    return load_text(cls, tomlfile.read_text(p, error, what), str(p), error, entries=entries)


def load_text(cls: type[T], text: str, where: str, error: type[Exception], *, entries: bool = False) -> Loaded[T]:
    return load_doc(cls, tomlfile.parse(text, where, error), where, error, entries=entries)


def load_doc(cls: type[T], doc: Mapping[str, Any], where: str, error: type[Exception], *,
             entries: bool = False) -> Loaded[T]:
    """Load a parsed TOML document into ``cls``; ``error`` (one line, ``where`` and the key) on any fault."""
    ctx = _Ctx(cls, where, error, entries)
    value = _table(ctx, cls, doc, "")
    return Loaded(value, ctx.entries, where)


def _join(path: str, key: str | None) -> str:
    if not key:
        return path
    return f"{path}.{key}" if path else key


def _schema_path(path: str) -> str:
    return re.sub(r"\[\d+\]", "", path)


def _table(ctx: _Ctx, cls: type, table: Mapping[str, Any], path: str) -> Any:
    fields = _fields(cls)
    bykey = {f.key: f for f in fields}
    inside = f" (in {path})" if _schema_path(path) != path else ""
    for k, v in table.items():
        if k in bykey:
            continue
        name = _schema_path(_join(path, k))
        is_section = isinstance(v, dict) and not (ctx.entry_style and "value" in v)
        if is_section:
            secs = [f.key for f in fields if f.kind == "section"]
            allowed = f" (allowed: {', '.join(secs)})" if secs else ""
            raise ctx.fail("", f"unknown section '{name}'{inside}{closest(name, ctx.paths())}{allowed}")
        raise ctx.fail("", f"unknown key '{name}'{inside}{closest(name, ctx.paths())}")
    kw: dict[str, Any] = {}
    for f in fields:
        key = _join(path, f.key)
        if f.key not in table:
            if f.spec.required or not f.has_default:
                if f.kind == "section":
                    raise ctx.fail("", f"missing section [{_schema_path(key)}]{inside}")
                raise ctx.fail("", f"missing key '{_schema_path(key)}'{inside}")
            continue
        kw[f.name] = _value(ctx, f, table[f.key], key)
    obj = cls(**kw)
    check = getattr(cls, "_config_check", None)
    if check is not None:
        try:
            check(obj, frozenset(table))
        except Invalid as e:
            raise ctx.fail(_join(path, e.key), e.message) from None
    return obj


def _value(ctx: _Ctx, f: _F, v: Any, key: str) -> Any:
    if f.kind == "section":
        if not isinstance(v, dict):
            raise ctx.fail("", f"'{key}' must be a table ([{key}]), got {_got(v)}")
        return _table(ctx, f.sub, v, key)
    if f.kind == "tables":
        if not isinstance(v, list) or not all(isinstance(d, dict) for d in v):
            raise ctx.fail(key, f"expected one or more [[{_schema_path(key)}]] tables, got {_got(v)}")
        _count(ctx, f.spec, len(v), key)
        return tuple(_table(ctx, f.sub, d, f"{key}[{j + 1}]") for j, d in enumerate(v))
    if f.kind == "map":
        if not isinstance(v, dict):
            raise ctx.fail(key, f"expected a table of name = value, got {_got(v)}")
        return {k: _value(ctx, f.sub, x, _join(key, k)) for k, x in v.items()}
    # a leaf
    unit = f.spec.unit
    pre = ""
    if ctx.entry_style:
        if not isinstance(v, dict):
            raise ctx.fail(key, f"expected a table {{ value, unit, source }}, got {_got(v)}")
        extra = sorted(set(v) - {"value", "unit", "source"})
        if extra:
            raise ctx.fail(key, f"expected a table {{ value, unit, source }}, not the field '{extra[0]}'")
        for part in ("value", "unit", "source"):
            if part not in v:
                raise ctx.fail(key, f"expected a table {{ value, unit, source }}, missing field '{part}'")
        if not isinstance(v["source"], str) or not v["source"].strip():
            raise ctx.fail(key, f"'source' must be a non-empty string, got {_got(v['source'])}")
        if not isinstance(v["unit"], str):
            raise ctx.fail(key, f"'unit' must be a string, got {_got(v['unit'])}")
        unit = v["unit"]
        ctx.entries[key] = (unit, v["source"])
        v = v["value"]
        pre = "value "
    return _leaf(ctx, f, v, key, unit, pre)


def _count(ctx: _Ctx, spec: Spec, n: int, key: str) -> None:
    for r in spec.rules:
        if isinstance(r, Count):
            why = f" ({r.why})" if r.why else ""
            if n < r.lo:
                raise ctx.fail(key, f"must list at least {r.lo}{why}, got {n}")
            if r.hi is not None and n > r.hi:
                raise ctx.fail(key, f"must list at most {r.hi}{why}, got {n}")


def _number(ctx: _Ctx, v: Any, key: str, pre: str, suffix: str = "") -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ctx.fail(key, f"{pre}must be a number, got {_got(v)}{suffix}")
    x = float(v)
    if not math.isfinite(x):
        raise ctx.fail(key, f"{pre}must be finite, got {x}{suffix}")
    return x


def _leaf(ctx: _Ctx, f: _F, v: Any, key: str, unit: str | None, pre: str) -> Any:
    spec = f.spec
    if f.kind == "bool":
        if not isinstance(v, bool):
            raise ctx.fail(key, f"{pre}must be true or false, got {_got(v)}")
        return v
    if f.kind == "int":
        if isinstance(v, bool) or not isinstance(v, int):
            raise ctx.fail(key, f"{pre}must be an integer, got {_got(v)}")
        _rules(ctx, spec, v, key, pre, None, "")
        return int(v)
    if f.kind == "str":
        if not isinstance(v, str):
            raise ctx.fail(key, f"{pre}must be a string, got {_got(v)}")
        _choices(ctx, spec, [v], key, pre)
        _equals(ctx, spec, v, key, pre)
        return v
    if f.kind == "strs":
        items = [v] if (spec.scalar_ok and isinstance(v, str)) else v
        if not isinstance(items, list) or not all(isinstance(c, str) for c in items):
            what = "a name or an array of names" if spec.scalar_ok else "an array of strings"
            raise ctx.fail(key, f"{pre}must be {what}, got {_got(v)}")
        _count(ctx, spec, len(items), key)
        _choices(ctx, spec, items, key, pre)
        if any(isinstance(r, Unique) for r in spec.rules):
            dup = next((c for i, c in enumerate(items) if c in items[:i]), None)
            if dup is not None:
                raise ctx.fail(key, f"{pre}lists '{dup}' twice")
        _equals(ctx, spec, tuple(items), key, pre, shown=v)
        return tuple(items)
    if f.kind == "float":
        dim = spec.dim if isinstance(spec.dim, str) else spec.dim[0]
        x = _number(ctx, v, key, pre)
        fac = _unit_factor(ctx, unit, dim, key, "", spec.per)
        si = x * fac
        _rules(ctx, spec, si, key, pre, dim, _shown(x, si, fac, unit))
        return si
    if f.kind == "floats":
        n = f.n
        if n == ANY_LENGTH:  # a vector of any length (within the field's Count rule)
            if not isinstance(v, list):
                raise ctx.fail(key, f"{pre}must be a list of numbers, got {_got(v)}")
            n = len(v)
            _count(ctx, spec, n, key)
        if not isinstance(v, list) or len(v) != n:
            raise ctx.fail(key, f"{pre}must be a list of {n} numbers, got {_got(v)}")
        xs = [_number(ctx, x, key, pre, f" (element {i + 1} of {n})") for i, x in enumerate(v)]
        dims = spec.dim if isinstance(spec.dim, tuple) else (spec.dim,) * n
        units = _split_units(ctx, unit, n, key)
        if units is not None and unit is not None and "," not in unit and unit != SI and len(set(dims)) > 1:
            example = ",".join(si_unit(d) for d in dims)
            raise ctx.fail(key, f"one unit '{unit}' for elements of {' and '.join(dict.fromkeys(dims))}: "
                                f"give one per element (e.g. '{example}') or two for the halves")
        out = []
        for i, x in enumerate(xs):
            el = f" of element {i + 1}" if units is not None and len(set(units)) > 1 else ""
            fac = _unit_factor(ctx, None if units is None else units[i], dims[i], key, el, spec.per)
            si = x * fac
            _rules(ctx, spec, si, key, pre, dims[i], _shown(x, si, fac, None if units is None else units[i])
                   + f" (element {i + 1} of {n})")
            out.append(si)
        return tuple(out)
    raise AssertionError(f.kind)  # pragma: no cover


def _shown(x: float, si: float, fac: float, unit: str | None) -> str:
    return f"{x!r}" if fac == 1.0 else f"{x!r} {unit} (= {si:g} SI)"


def _split_units(ctx: _Ctx, unit: str | None, n: int, key: str) -> list[str] | None:
    if unit is None:
        return None
    parts = [u.strip() for u in unit.split(",")]
    if len(parts) == 1:
        return parts * n
    if len(parts) == n:
        return parts
    if len(parts) == 2 and n % 2 == 0:
        return [parts[0]] * (n // 2) + [parts[1]] * (n // 2)
    raise ctx.fail(key, f"unit list '{unit}' does not match {n} values "
                        f"(give one unit, one per element, or two for the halves)")


def _unit_factor(ctx: _Ctx, unit: str | None, dim: str, key: str, el: str, per: str | None = None) -> float:
    """SI factor of ``unit`` for a value of dimension ``dim`` (None: the number is SI)."""
    if unit is None or unit == SI:
        return 1.0
    dims = dim.split(" or ")
    bare = unit[: -len(f" per {per}")] if per and unit.endswith(f" per {per}") else unit
    parts = [u.strip() for u in bare.split(" or ")]
    allowed = ", ".join(_allowed(dim))
    if len(parts) != len(dims):
        raise ctx.fail(key, f"unit '{unit}'{el} is not {_a(dim)} (allowed: {allowed})")
    facs = []
    for u, d in zip(parts, dims):
        if u not in UNITS:
            raise ctx.fail(key, f"unknown unit '{u}'{el} (allowed for {_a(dim)}: {allowed})")
        udim, fac = UNITS[u]
        if udim != d:
            raise ctx.fail(key, f"unit '{unit}'{el} is not {_a(dim)} (allowed: {allowed})")
        facs.append(fac)
    if len(set(facs)) != 1:
        raise ctx.fail(key, f"unit '{unit}'{el}: one number for {' and '.join(dims)} needs units of one scale "
                            f"(allowed: {allowed})")
    return facs[0]


def _rules(ctx: _Ctx, spec: Spec, x: float, key: str, pre: str, dim: str | None, shown: str) -> None:
    for r in spec.rules:
        if isinstance(r, Bound):
            p = r.problem(x, dim)
            if p is not None:
                raise ctx.fail(key, f"{pre}{p}, got {shown or repr(x)}")


def _choices(ctx: _Ctx, spec: Spec, items: list[str], key: str, pre: str) -> None:
    for r in spec.rules:
        if isinstance(r, Choices):
            for c in items:
                if c not in r.options:
                    raise ctx.fail(key, f"{pre}unknown {r.noun} '{c}'{closest(c, r.options, 0.5)} "
                                        f"(allowed: {', '.join(r.options)})")


def _equals(ctx: _Ctx, spec: Spec, v: Any, key: str, pre: str, shown: Any = None) -> None:
    for r in spec.rules:
        if isinstance(r, Equals) and v != r.value:
            want = list(r.value) if isinstance(r.value, tuple) else r.value
            why = f" ({r.why})" if r.why else ""
            raise ctx.fail(key, f"{pre}must be {want!r}{why}, got {(v if shown is None else shown)!r}")


@functools.lru_cache(maxsize=None)
def _leaf_by_key(cls: type) -> dict[str, Leaf]:
    return {x.key: x for x in leaves(cls)}


def check_value(cls: type, key: str, value: Any, where: str, error: type[Exception]) -> Any:
    """Check an SI value against the rules of leaf ``key`` of ``cls`` (e.g. a value replaced at run time)."""
    leaf = _leaf_by_key(cls).get(key)
    if leaf is None:
        raise error(f"{where}: unknown key '{key}'{closest(key, [x.key for x in leaves(cls)])}")
    ctx = _Ctx(cls, where, error, entry_style=True)
    f = _F(leaf.attrs[-1], key, leaf.kind, leaf.spec, False, False, None, leaf.n)
    if leaf.kind == "float" and isinstance(value, numbers.Real) and not isinstance(value, bool):
        value = float(value)  # NumPy scalars too
    return _leaf(ctx, f, value, key, None, "value ")


# ---- memory ----------------------------------------------------------------------------------------


def format_bytes(n: float) -> str:
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n:.0f} B"


def check_memory(nbytes: float, what: str, where: str, key: str, error: type[Exception]) -> None:
    """Refuse a request whose tables would exceed :data:`MEMORY_CAP_BYTES` (one line, before any work)."""
    if nbytes > MEMORY_CAP_BYTES:
        raise error(f"{where}: {key}: {what} would need about {format_bytes(nbytes)}, more than the "
                    f"{format_bytes(MEMORY_CAP_BYTES)} cap (arvcas.system.config.MEMORY_CAP_BYTES)")
