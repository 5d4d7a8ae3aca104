"""The system file's structure: what a file describes, read before its numbers (docs/system-file.md).

A system file describes one vehicle, its thrusters and its arm. Its *structure* (which hydrodynamic
terms, how many thrusters and joints, which arm form) decides the shape of the compiled code; its
*numbers* are runtime parameters. :func:`structure_of` reads the structure from the parsed document
and :func:`schema_for` builds the strict schema (:mod:`arvcas.system.config` dataclasses) of exactly that
structure, so the numbers load with the one configuration loader: units, rules, closest-name hints.
"""

from __future__ import annotations

import dataclasses
import keyword
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from arvcas.system import config
from arvcas.system.config import ge, gt, lt, quantity

__all__ = [
    "HydroTerm", "Structure", "ThrusterMap", "ThrusterDynamics", "parse_term", "structure_of", "schema_for",
    "MAX_JOINTS", "DOF_NAMES", "VECTOR_ELEMENTS", "HYDRO_ALIASES", "FORMS", "COMMAND_UNITS", "element_labels", "read_tables",
]

MAX_JOINTS = 7
DOF_NAMES = ("surge", "sway", "heave", "roll", "pitch", "yaw")  # [thrusters] unactuated = [...] names them
FORCES = "XYZKMN"
VELOCITIES = "uvwpqr"
FORMS = ("dh", "chain", "urdf")
NAME_RE = re.compile(r"^[a-z][a-z0-9_]{0,63}\Z")  # \Z: "$" would accept a final newline
THRUSTER_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,31}\Z")

# Table A1's names for its four stern-angle terms: aliases of their full term names (docs/model.md §2).
HYDRO_ALIASES = {
    "X_ds": "X_w_absw_ds",
    "Z_dsds": "Z_w_absw_ds2",
    "M_ds": "M_w_ds_w",
    "M_dsds": "M_w_ds2_absw",
}

# a thruster command map's command units (docs/system-file.md): PWM pulse width, normalised, rotor speed;
# each with the dimension of the command and of its rate (arvcas.system.config.UNITS)
COMMAND_UNITS = {"us": ("pwm", "pwm_rate"), "1": ("1", "rate"), "rad/s": ("angular_velocity", "angular_acceleration")}
TABLE_VECTORS = ("command", "thrust")  # a table map's two columns: parameters <key>.0 .. <key>.<n-1>
MAX_TABLE_POINTS = 10_000

# the parametric thruster layout of the paper's Appendix B (a [thrusters] table of delta_sL ... x_hS, no
# [[thrusters.unit]] list; Haidou-1's): its six thrusters in the order of B's columns (arvcas.model.thrusters:
# stern left and right, rotatable; side thrusters at the bow and the stern; verticals)
PARAMETRIC_THRUSTERS = ("T1 stern left", "T2 stern right", "T3 side (bow)", "T4 side (stern)", "T5 vertical (port)",
                     "T6 vertical (starboard)")
# element labels of the vector entries: parameter ``<key>.<label>``
VECTOR_ELEMENTS = {
    "position": ("x", "y", "z"), "direction": ("x", "y", "z"), "axis": ("x", "y", "z"),
    "com": ("x", "y", "z"), "cob": ("x", "y", "z"), "drag_from": ("x", "y", "z"), "drag_to": ("x", "y", "z"),
    "inertia": ("ixx", "iyy", "izz", "ixy", "ixz", "iyz"),
}


class _Bad(ValueError):
    pass


def element_labels(key: str, n: int) -> tuple[str, ...]:
    """The labels of a vector entry's elements (parameter ``<key>.<label>``): x y z ... or, for a thrust
    table's columns, the point's index 0 .. n-1."""
    last = key.rsplit(".", 1)[-1]
    if last in TABLE_VECTORS and ".map." in key:
        return tuple(str(i) for i in range(n))
    return VECTOR_ELEMENTS[last]


@dataclass(frozen=True)
class HydroTerm:
    """One hydrodynamic derivative: ``coef * prod(factors)`` added to force ``row``.

    Damping: ``col`` is the velocity the term multiplies (the damping matrix's column) and ``factors``
    the rest of the product; added mass: ``dot`` is the accelerated velocity, ``col`` is None.
    """

    name: str
    row: int
    col: int | None
    dot: int | None
    factors: tuple[str, ...]

    def order(self) -> tuple:
        """The order of terms within one damping-matrix entry: fewer factors first, then by factor name."""
        return (len(self.factors), self.factors)


def _valid_examples() -> list[str]:
    out = list(HYDRO_ALIASES)
    for F in FORCES:
        for v in VELOCITIES:
            out += [f"{F}_{v}", f"{F}_{v}_abs{v}", f"{F}_{v}dot"]
    return out


def parse_term(name: str) -> HydroTerm:
    """The term a derivative's name defines (docs/system-file.md); ValueError (one line) if it defines none."""
    full = HYDRO_ALIASES.get(name, name)
    toks = full.split("_")

    def hint() -> str:  # the closest valid names, computed only for a refusal (difflib: ~3 ms a name)
        return config.closest(name, _valid_examples())

    if len(toks) < 2 or toks[0] not in FORCES or len(toks[0]) != 1:
        raise _Bad(f"'{name}' is not a derivative name: it must be <F>_<factor>... with <F> one of "
                   f"{', '.join(FORCES)}{hint()}")
    row = FORCES.index(toks[0])
    rest = toks[1:]
    if len(rest) == 1 and rest[0].endswith("dot") and len(rest[0]) == 4 and rest[0][0] in VELOCITIES:
        return HydroTerm(name, row, None, VELOCITIES.index(rest[0][0]), ())
    factors: list[str] = []
    for t in rest:
        if t.startswith("abs") and len(t) == 4 and t[3] in VELOCITIES:
            factors.append(t)
        elif t in ("ds", "ds2"):
            factors.append(t)
        elif t and all(c in VELOCITIES for c in t):
            factors += list(t)
        else:
            raise _Bad(f"'{name}': unknown factor '{t}' (factors: u v w p q r, absu .. absr, udot .. rdot "
                       f"alone, ds, ds2){hint()}")
    plain = [i for i, f in enumerate(factors) if len(f) == 1]
    if not plain:
        raise _Bad(f"'{name}': a damping term needs a velocity factor (u v w p q r){hint()}")
    i0 = plain[0]
    col = VELOCITIES.index(factors[i0])
    return HydroTerm(name, row, col, None, tuple(factors[:i0] + factors[i0 + 1:]))


@dataclass(frozen=True)
class Structure:
    """What a system file describes (everything that shapes the compiled code; numbers excluded)."""

    name: str
    buoyancy: str  # "excess" (kg above m) | "volume" (displaced m^3)
    hydro: tuple[HydroTerm, ...]  # in file order
    hydro_per_rho: bool  # "per_rho" units (SI coefficient rho * value) or "SI"
    coriolis_added_mass: bool
    thrusters: tuple[str, ...] | None  # names of a thruster list; None: the parametric layout (Appendix B)
    arm: str  # "none" | "dh" | "chain"
    n_joints: int
    mount_rpy: bool
    link_drag: tuple[bool, ...]  # chain: the link has a drag segment
    link_cd: tuple[bool, ...]  # chain: the link has its own Cd
    arm_trim: bool = True  # docs/model.md §3's trim buoyancy for the stowed arm (``[arm] trim = false``: none)
    thruster_maps: tuple["ThrusterMap", ...] = ()  # command maps, [thrusters.map.<name>]
    thruster_dynamics: tuple["ThrusterDynamics", ...] | None = None  # per listed thruster, or None: instantaneous
    # DOFs (0..5: surge .. yaw) the thrusters leave to the vehicle's own statics; out of the repr so that every
    # fully actuated system keeps its key (and its compiled code's name)
    unactuated: tuple[int, ...] = dataclasses.field(default=(), repr=False)
    env_cd: bool = dataclasses.field(default=True, repr=False)  # [env] Cd given (optional without an arm)

    @property
    def n_thrusters(self) -> int:
        return 6 if self.thrusters is None else len(self.thrusters)

    @property
    def has_thruster_dynamics(self) -> bool:
        return self.thruster_dynamics is not None

    def thruster_map(self, name: str) -> "ThrusterMap":
        return next(m for m in self.thruster_maps if m.name == name)

    def instantaneous(self) -> "Structure":
        """The same system with thrusters that deliver their (saturated) command at once."""
        return dataclasses.replace(self, thruster_maps=(), thruster_dynamics=None)

    def thruster_names(self) -> tuple[str, ...]:
        """The thrusters' names in allocation order (the columns of B): the list's, or the parametric layout's six."""
        return PARAMETRIC_THRUSTERS if self.thrusters is None else self.thrusters

    def key(self) -> str:
        """A stable text of the structure, for compile-cache keys."""
        return (repr(self) + (f" unactuated={self.unactuated}" if self.unactuated else "")
                + ("" if self.env_cd else " env_cd=False"))


@dataclass(frozen=True)
class ThrusterMap:
    """A command map (docs/system-file.md): from the command the autopilot sends to steady thrust.

    ``kind``: ``"table"`` (points ``command.i -> thrust.i``, the monotone cubic through them; its run of zero
    thrust is the dead band, ``zero = (first, last)`` index of that run) or ``"quadratic"`` (uuv_simulator's rotor law
    ``T = k s |s|`` on the command ``s`` beyond a dead band). ``unit``: the command's unit (COMMAND_UNITS).
    """

    name: str
    kind: str
    unit: str
    n: int = 0  # table points
    zero: tuple[int, int] = (0, 0)  # table: first and last index of the zero-thrust run (the dead band)
    uniform: bool = False  # table: its commands are evenly spaced (a lookup is one division)


@dataclass(frozen=True)
class ThrusterDynamics:
    """One thruster's dynamics: its map, a first-order lag (one time constant, or one for spin-up and one
    for spin-down: ``asymmetric``) and an optional rate limit (docs/model.md §9)."""

    map: str
    asymmetric: bool
    rate_limit: bool


# ---- reading the structure --------------------------------------------------------------------------


def _table(doc: Any, key: str, where: str, required: bool = True) -> dict:
    v = doc.get(key) if isinstance(doc, dict) else None
    if v is None:
        if required:
            raise _Bad(f"{key}: missing section")
        return {}
    if not isinstance(v, dict):
        raise _Bad(f"{key}: expected a table, got {type(v).__name__}")
    return v


def _numbered(table: dict, prefix: str, path: str) -> int:
    """The count n of tables ``<prefix>1 .. <prefix>n`` in ``table`` (no gaps)."""
    idx = sorted(int(k[len(prefix):]) for k in table if re.fullmatch(rf"{prefix}[1-9][0-9]*", k))
    if idx and idx != list(range(1, len(idx) + 1)):
        missing = sorted(set(range(1, max(idx) + 1)) - set(idx))
        raise _Bad(f"{path}.{prefix}{missing[0]}: missing (joints and links are numbered 1 .. n without gaps)")
    return len(idx)


def _thruster_name(n: Any, i: int) -> str:
    """A thruster's name: an identifier of at most 32 characters that is not a Python keyword (it names a
    field of the file's schema, a parameter and a signal)."""
    if not isinstance(n, str) or not THRUSTER_RE.match(n):
        raise _Bad(f"thrusters.unit[{i}].name: expected a name like \"T1\" ([A-Za-z][A-Za-z0-9_]*, at most 32 "
                   f"characters), got {n!r}")
    if keyword.iskeyword(n):
        raise _Bad(f"thrusters.unit[{i}].name: {n!r} is a Python keyword; choose another name (like \"T1\")")
    return n


_SYSTEM_KEYS = ("name", "description", "accept_implausible")


def _check_system_keys(sysd: dict) -> None:
    """``[system]`` has a name, a description and ``accept_implausible`` (true: the plausibility rules of
    docs/system-file.md warn instead of refusing; it shapes no code)."""
    for k in sysd:
        if k not in _SYSTEM_KEYS:
            raise _Bad(f"system.{k}: unknown key (allowed: {', '.join(_SYSTEM_KEYS)}){config.closest(k, _SYSTEM_KEYS)}")
    if not isinstance(sysd.get("accept_implausible", False), bool):
        raise _Bad(f"system.accept_implausible: expected true or false, got {sysd['accept_implausible']!r}")


def structure_of(doc: dict, where: str, error: type[Exception], default_name: str = "") -> Structure:
    """The :class:`Structure` of a parsed system file; ``error`` (one line naming ``where`` and the key)."""
    try:
        return _structure(doc, default_name)
    except _Bad as e:
        raise error(f"{where}: {e}") from None


def _structure(doc: dict, default_name: str) -> Structure:
    sysd = _table(doc, "system", "", required=False)
    _check_system_keys(sysd)
    if not isinstance(sysd.get("description", ""), str):
        raise _Bad("system.description: expected a string")
    dfl = doc.get("defaults", {})
    if not isinstance(dfl, dict):
        raise _Bad("defaults: expected a table")
    for k, v in dfl.items():
        if k not in ("scenario", "gains"):
            raise _Bad(f"defaults.{k}: unknown key (allowed: scenario, gains){config.closest(k, ['scenario', 'gains'])}")
        if not isinstance(v, str) or not v:
            raise _Bad(f"defaults.{k}: expected a file name (relative to the system file), got {v!r}")
    name = sysd.get("name", default_name)
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise _Bad(f"system.name: {name!r} must match [a-z][a-z0-9_]* (it names compiled code and files)")
    veh = _table(doc, "vehicle", "")
    has_ex, has_vol = "buoyancy_excess" in veh, "volume" in veh
    if has_ex == has_vol:
        raise _Bad("vehicle: give exactly one of 'buoyancy_excess' (kg) and 'volume' (m^3)")
    hyd = _table(doc, "hydro", "")
    cam = hyd.get("coriolis_added_mass", False)
    if not isinstance(cam, bool):
        raise _Bad(f"hydro.coriolis_added_mass: expected true or false, got {cam!r}")
    terms, units = [], set()
    for k, v in hyd.items():
        if k == "coriolis_added_mass":
            continue
        try:
            terms.append(parse_term(k))
        except _Bad as e:
            raise _Bad(f"hydro.{k}: {e}") from None
        if isinstance(v, dict) and isinstance(v.get("unit"), str):
            units.add(v["unit"])
    seen: dict[tuple, str] = {}
    for t in terms:
        sig = (t.row, t.col, t.dot, t.factors)
        if sig in seen:
            raise _Bad(f"hydro.{t.name}: the same term as hydro.{seen[sig]}")
        seen[sig] = t.name
    if units - {"per_rho", "SI"} or len(units) > 1:
        raise _Bad(f"hydro: every derivative's unit must be \"per_rho\" (SI value = rho * value) or every "
                   f"one \"SI\", got {', '.join(sorted(units))}")
    per_rho = units == {"per_rho"}
    thr = _table(doc, "thrusters", "")
    if "unit" in thr:
        units_list = thr["unit"]
        extra = [k for k in thr if k not in ("unit", "map", "unactuated")]
        if extra:
            raise _Bad(f"thrusters.{extra[0]}: a thruster list ([[thrusters.unit]]) takes no other keys than "
                       f"[thrusters.map.<name>] command maps and unactuated")
        unact = _unactuated(thr.get("unactuated", []))
        if not isinstance(units_list, list) or not all(isinstance(u, dict) for u in units_list):
            raise _Bad("thrusters.unit: expected an array of tables [[thrusters.unit]]")
        names = []
        for i, u in enumerate(units_list):
            n = _thruster_name(u.get("name"), i)
            if n in names:
                raise _Bad(f"thrusters.unit[{i}].name: '{n}' is used twice")
            if n == "map":
                raise _Bad(f"thrusters.unit[{i}].name: 'map' names the command maps ([thrusters.map.<name>])")
            names.append(n)
        if len(names) < 6 - len(unact):
            raise _Bad(f"thrusters.unit: {len(names)} thrusters cannot produce a wrench in {6 - len(unact)} degrees "
                       f"of freedom (at least {6 - len(unact)})")
        maps = _maps(thr.get("map", {}))
        dyn = _dynamics(units_list, names, maps)
        thrusters: tuple[str, ...] | None = tuple(names)
        if any(f in ("ds", "ds2") for t in terms for f in t.factors):
            bad = next(t.name for t in terms if any(f in ("ds", "ds2") for f in t.factors))
            raise _Bad(f"hydro.{bad}: the stern-angle factor ds needs Haidou-1's thruster layout "
                       f"(thrusters.delta_sL, delta_sR)")
    else:
        thrusters, maps, dyn, unact = None, (), None, ()
    vehicle_only = (name, "excess" if has_ex else "volume", tuple(terms), per_rho, cam, thrusters)
    extra = {"thruster_maps": maps, "thruster_dynamics": dyn, "unactuated": unact}
    st = _with_arm(doc, vehicle_only)
    env = doc.get("env")
    # the arm links' drag coefficient: a system without an arm may leave it out
    cd = st.n_joints > 0 or not isinstance(env, dict) or "Cd" in env
    return dataclasses.replace(st, env_cd=cd, **extra)


def _unactuated(v: Any) -> tuple[int, ...]:
    """``[thrusters] unactuated = ["pitch"]``: the degrees of freedom the thrusters cannot move on their own
    (a six-thruster BlueROV2 has no pitch: its allocation matrix has rank 5), in DOF order."""
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise _Bad(f"thrusters.unactuated: expected a list of degree-of-freedom names ({', '.join(DOF_NAMES)}), "
                   f"got {v!r}")
    for x in v:
        if x not in DOF_NAMES:
            raise _Bad(f"thrusters.unactuated: {x!r} is not a degree of freedom (allowed: {', '.join(DOF_NAMES)})"
                       f"{config.closest(x, DOF_NAMES)}")
    if len(set(v)) != len(v):
        raise _Bad(f"thrusters.unactuated: a degree of freedom is named twice: {v!r}")
    if len(v) > 2:
        raise _Bad(f"thrusters.unactuated: {len(v)} degrees of freedom left unactuated; at most 2 (a vehicle the "
                   f"thrusters hold in at least four)")
    return tuple(sorted(DOF_NAMES.index(x) for x in v))


def _with_arm(doc: dict, vehicle_only: tuple) -> Structure:
    arm = doc.get("arm")
    if arm is None:
        return Structure(*vehicle_only, "none", 0, False, (), ())
    if not isinstance(arm, dict):
        raise _Bad("arm: expected a table")
    if "urdf" in arm:
        raise _Bad("arm.urdf: internal: a URDF arm is converted before its structure is read")
    nj = _numbered(arm, "joint", "arm")
    nl = _numbered(arm, "link", "arm")
    if nj > MAX_JOINTS:
        raise _Bad(f"arm: {nj} joints, at most {MAX_JOINTS} are supported")
    if nl != nj:
        raise _Bad(f"arm: {nj} joints but {nl} links (each joint moves one link: arm.link1 .. arm.link{nj})")
    trim = arm.get("trim", True)
    if not isinstance(trim, bool):
        raise _Bad(f"arm.trim: expected true or false, got {trim!r}")
    mount = _table(arm, "mount", "arm") if nj else arm.get("mount", {})
    rpy = [k for k in ("roll", "pitch", "yaw") if k in mount]
    if rpy and len(rpy) != 3:
        raise _Bad("arm.mount: give all of roll, pitch, yaw or none")
    if nj == 0:
        return Structure(*vehicle_only, "none", 0, False, (), ())
    j1 = arm["joint1"]
    if not isinstance(j1, dict):
        raise _Bad("arm.joint1: expected a table")
    form = "dh" if "a" in j1 or "alpha" in j1 else "chain"
    drag, cd = [], []
    for i in range(1, nj + 1):
        lk = arm[f"link{i}"]
        if not isinstance(lk, dict):
            raise _Bad(f"arm.link{i}: expected a table")
        if form == "chain":
            have = [k for k in ("drag_diameter", "drag_from", "drag_to") if k in lk]
            if have and len(have) != 3:
                raise _Bad(f"arm.link{i}: a drag segment needs drag_diameter, drag_from and drag_to (or none)")
            drag.append(bool(have))
            cd.append("Cd" in lk)
    return Structure(*vehicle_only, form, nj, bool(rpy), tuple(drag), tuple(cd), trim)


_DYN_KEYS = ("map", "time_constant", "time_constant_up", "time_constant_down", "rate_limit")
_MAP_NAME_RE = re.compile(r"^[a-z][a-z0-9_]{0,63}$")


def _maps(table: Any) -> tuple[ThrusterMap, ...]:
    """The command maps of ``[thrusters.map.<name>]`` (a table: ``command`` and ``thrust`` vectors, written
    inline or read from ``table = "file.csv"`` by :func:`read_tables`; or the quadratic rotor law)."""
    if not isinstance(table, dict):
        raise _Bad("thrusters.map: expected tables [thrusters.map.<name>]")
    out = []
    for name, m in table.items():
        key = f"thrusters.map.{name}"
        if not _MAP_NAME_RE.match(name):
            raise _Bad(f"{key}: a map's name must match [a-z][a-z0-9_]*")
        if not isinstance(m, dict):
            raise _Bad(f"{key}: expected a table")
        if "command" in m or "thrust" in m:
            for k in TABLE_VECTORS:
                if not isinstance(m.get(k), dict) or not isinstance(m[k].get("value"), list):
                    raise _Bad(f"{key}.{k}: a table map needs command and thrust vectors {{ value = [...], unit, "
                               f"source }} (or table = \"file.csv\")")
            unit = m["command"].get("unit")
            if unit not in COMMAND_UNITS:
                raise _Bad(f"{key}.command: unit {unit!r}: a command is in one of {', '.join(COMMAND_UNITS)} "
                           f"(PWM microseconds, normalised, rotor speed)")
            out.append(ThrusterMap(name, "table", unit, *_table_shape(m, key)))
        else:
            unit = m.get("command_unit")
            if unit not in ("1", "rad/s"):
                raise _Bad(f"{key}.command_unit: the quadratic rotor law takes a normalised (\"1\") or rotor-speed "
                           f"(\"rad/s\") command, got {unit!r} (a PWM map is a table)")
            out.append(ThrusterMap(name, "quadratic", unit))
    return tuple(out)


def _table_shape(m: dict, key: str) -> tuple[int, tuple[int, int], bool]:
    """(points, (first, last) index of the zero-thrust run, evenly spaced commands) of a table map; one line
    for a table that is not a monotonic map with a dead band around zero thrust."""
    c, t = m["command"]["value"], m["thrust"]["value"]
    n = len(c)
    if len(t) != n:
        raise _Bad(f"{key}: {n} commands but {len(t)} thrusts")
    if not 4 <= n <= MAX_TABLE_POINTS:
        raise _Bad(f"{key}.command: {n} points, a table needs 4 to {MAX_TABLE_POINTS}")
    for k, v in (("command", c), ("thrust", t)):
        bad = next((i for i, x in enumerate(v) if isinstance(x, bool) or not isinstance(x, (int, float))
                    or x != x or x in (float("inf"), float("-inf"))), None)
        if bad is not None:
            raise _Bad(f"{key}.{k}: point {bad}: expected a finite number, got {v[bad]!r}")
    for i in range(1, n):
        if not c[i] > c[i - 1]:
            raise _Bad(f"{key}.command: not increasing at point {i} ({c[i - 1]:g} then {c[i]:g})")
        if t[i] < t[i - 1]:
            raise _Bad(f"{key}.thrust: a non-monotonic thrust table: thrust falls from {t[i - 1]:g} to {t[i]:g} at "
                       f"point {i} (command {c[i]:g}); more command must give at least as much thrust")
        if t[i] == t[i - 1] and t[i] != 0 and not (t[i] == t[0] or t[i] == t[-1]):
            raise _Bad(f"{key}.thrust: thrust {t[i]:g} at points {i - 1} and {i}: flat only at zero thrust "
                       f"(the dead band) and at the table's ends (the saturation plateaus); the map must be "
                       f"invertible elsewhere")
    zeros = [i for i, x in enumerate(t) if x == 0]
    if not zeros or t[0] >= 0 or t[-1] <= 0:
        raise _Bad(f"{key}.thrust: the table must run from reverse (< 0) through zero thrust (the dead band, "
                   f"one point or more) to forward (> 0) thrust")
    step = (c[-1] - c[0]) / (n - 1)
    uniform = all(abs(c[i] - (c[0] + i * step)) <= 1e-9 * max(abs(c[0]), abs(c[-1])) for i in range(n))
    return n, (zeros[0], zeros[-1]), uniform


def _dynamics(units: list, names: list[str], maps: tuple[ThrusterMap, ...]) -> tuple[ThrusterDynamics, ...] | None:
    """Each listed thruster's dynamics (all or none), checked against the declared maps."""
    has = [any(k in u for k in _DYN_KEYS) for u in units]
    if not any(has):
        if maps:
            raise _Bad(f"thrusters.map.{maps[0].name}: declared but no thruster uses it (give each thruster map = "
                       f"\"{maps[0].name}\" and its time_constant)")
        return None
    if not all(has):
        i = has.index(False)
        raise _Bad(f"thrusters.unit[{i}] ({names[i]}): thruster dynamics are declared for every thruster or none "
                   f"(map, time_constant or time_constant_up/_down, optional rate_limit)")
    out, used = [], set()
    for i, u in enumerate(units):
        key = f"thrusters.unit[{i}] ({names[i]})"
        m = u.get("map")
        if not isinstance(m, str) or not any(x.name == m for x in maps):
            raise _Bad(f"{key}.map: expected the name of a [thrusters.map.<name>] table"
                       f"{config.closest(str(m), [x.name for x in maps])} (declared: "
                       f"{', '.join(x.name for x in maps) or 'none'})")
        used.add(m)
        sym, up, down = "time_constant" in u, "time_constant_up" in u, "time_constant_down" in u
        if sym == (up or down) or up != down:
            raise _Bad(f"{key}: give time_constant, or both time_constant_up and time_constant_down")
        out.append(ThrusterDynamics(m, up, "rate_limit" in u))
    unused = [x.name for x in maps if x.name not in used]
    if unused:
        raise _Bad(f"thrusters.map.{unused[0]}: declared but no thruster uses it")
    return tuple(out)


def read_tables(doc: dict, path: str | Path, error: type[Exception]) -> dict:
    """``doc`` with each ``[thrusters.map.<name>] table = "file.csv"`` read into its ``command`` and
    ``thrust`` entries (the file: ``#`` comment lines, one ``# source: ...`` line, a header
    ``<name> [<command unit>],<name> [<force unit>]``, then one ``command,thrust`` row per point)."""
    thr = doc.get("thrusters")
    maps = thr.get("map") if isinstance(thr, dict) else None
    if not isinstance(maps, dict) or not any(isinstance(m, dict) and "table" in m for m in maps.values()):
        return doc
    from arvcas.util.files import read_text

    new = {}
    for name, m in maps.items():
        if not (isinstance(m, dict) and "table" in m):
            new[name] = m
            continue
        key = f"thrusters.map.{name}"
        extra = [k for k in m if k != "table"]
        if extra or not isinstance(m["table"], str):
            raise error(f"{path}: {key}: a table file map takes only table = \"file.csv\""
                        + (f" (not {extra[0]})" if extra else ""))
        cpath = _table_path(path, m["table"])
        if cpath is None:
            raise error(f"{path}: {key}.table: {m['table']!r} is neither beside the system file nor a shipped "
                        f"table (arvcas/data: {', '.join(shipped_tables()) or 'none'})")
        text = read_text(cpath, "thrust table", lambda msg: error(f"{path}: {key}.table: {msg}"))
        new[name] = {"table": m["table"], **_parse_csv(text, f"{path}: {key}.table: {cpath}", error)}
    return {**doc, "thrusters": {**thr, "map": new}}


def shipped_tables() -> list[str]:
    """The thrust tables shipped in ``arvcas/data`` (a system file may name them from anywhere)."""
    from importlib import resources

    return sorted(p.name for p in Path(str(resources.files("arvcas") / "data")).glob("*.csv"))


def _table_path(system: str | Path, name: str) -> Path | None:
    """A thrust table beside the system file, else a shipped one of that name, else None."""
    p = rel_path(system, name)
    if p.exists():
        return p
    if Path(name).name == name and name in shipped_tables():
        from importlib import resources

        return Path(str(resources.files("arvcas") / "data" / name))
    return None


def _parse_csv(text: str, where: str, error) -> dict:
    source, header, rows = None, None, []
    for ln, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            body = s[1:].strip()
            if body.lower().startswith("source:"):
                source = body.split(":", 1)[1].strip()
            continue
        cells = [c.strip() for c in s.split(",")]
        if header is None:
            m = [re.fullmatch(r"([A-Za-z_][A-Za-z0-9_ ]*)\[([^\]]+)\]", c) for c in cells]
            if len(cells) != 2 or not all(m):
                raise error(f"{where}: line {ln}: expected a header 'command [unit],thrust [unit]', got {s!r}")
            header = [x.group(2).strip() for x in m]
            continue
        if len(cells) != 2:
            raise error(f"{where}: line {ln}: expected 2 numbers (command, thrust), got {len(cells)}")
        try:
            rows.append((float(cells[0]), float(cells[1])))
        except ValueError:
            raise error(f"{where}: line {ln}: not a number: {s!r}") from None
    if not source:
        raise error(f"{where}: no '# source: ...' line (every number carries its source)")
    if header is None or not rows:
        raise error(f"{where}: no header and rows")
    return {"command": {"value": [r[0] for r in rows], "unit": header[0], "source": source},
            "thrust": {"value": [r[1] for r in rows], "unit": header[1], "source": source}}


# ---- the schema of one structure ------------------------------------------------------------------------


@dataclass(frozen=True)
class Env:
    rho: float = quantity("density", ge(0))  # rho = 0 is the no-fluid reference case
    g: float = quantity("acceleration", gt(0))
    Cd: float = quantity("1", ge(0))


@dataclass(frozen=True)
class EnvNoArm:
    """``[env]`` of a system without an arm that gives no ``Cd`` (the drag coefficient of arm links)."""

    rho: float = quantity("density", ge(0))
    g: float = quantity("acceleration", gt(0))


_CG_CB = ("xG", "yG", "zG", "xB", "yB", "zB")


def _vehicle_cls(buoyancy: str) -> type:
    fields = [("m", float, quantity("mass", gt(0))),
              ("buoyancy_excess", float, quantity("mass")) if buoyancy == "excess"
              else ("volume", float, quantity("volume", ge(0)))]
    fields += [(k, float, quantity("inertia", gt(0))) for k in ("Ixx", "Iyy", "Izz")]
    fields += [(k, float, quantity("inertia")) for k in ("Ixy", "Iyz", "Ixz")]
    fields += [(k, float, quantity("length")) for k in _CG_CB]
    return dataclasses.make_dataclass("Vehicle", fields, frozen=True)


@dataclass(frozen=True)
class HaidouThrusters:
    """Haidou-1's parametric layout (Appendix B): two rotatable stern, two side, two vertical thrusters."""

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
class Thruster:
    position: tuple[float, ...] = quantity("length", n=3)
    direction: tuple[float, ...] = quantity("1", n=3)
    u_min: float = quantity("force")
    u_max: float = quantity("force")


def _thruster_cls(dyn: ThrusterDynamics | None, unit: str) -> type:
    """A listed thruster's schema: geometry and limits, then its dynamics (docs/system-file.md)."""
    if dyn is None:
        return Thruster
    def tau():  # a new field each time (a dataclass field object belongs to one field)
        return quantity("time", gt(0, "a first-order lag's time constant"))

    fields = [(f.name, f.type, quantity(f.metadata[config._META].dim, n=f.metadata[config._META].n))
              for f in dataclasses.fields(Thruster)]
    if dyn.asymmetric:
        fields += [("time_constant_up", float, tau()), ("time_constant_down", float, tau())]
    else:
        fields.append(("time_constant", float, tau()))
    if dyn.rate_limit:
        fields.append(("rate_limit", float, quantity(COMMAND_UNITS[unit][1], gt(0))))
    return dataclasses.make_dataclass(f"Thruster{'A' if dyn.asymmetric else ''}{'R' if dyn.rate_limit else ''}_"
                                      f"{COMMAND_UNITS[unit][0]}", fields, frozen=True)


def _map_cls(m: ThrusterMap) -> type:
    dim = COMMAND_UNITS[m.unit][0]
    if m.kind == "table":
        fields = [("command", tuple[float, ...], quantity(dim, n=m.n)), ("thrust", tuple[float, ...],
                                                                         quantity("force", n=m.n))]
    else:
        k = "force" if m.unit == "1" else "rotor_constant"
        fields = [("rotor_constant", float, quantity(k, gt(0))), ("command_min", float, quantity(dim, lt(0))),
                  ("command_max", float, quantity(dim, gt(0))), ("dead_band", float, quantity(dim, ge(0)))]
    return dataclasses.make_dataclass(f"Map_{m.kind}_{m.n}_{dim}", fields, frozen=True)


@dataclass(frozen=True)
class Payload:
    mass: float = quantity("mass", ge(0))
    volume: float = quantity("volume", ge(0))


@dataclass(frozen=True)
class DHJoint:
    """Craig's modified DH row of joint i (a_{i-1}, d_i, alpha_{i-1}) and its limits (Table 1)."""

    a: float = quantity("length")
    d: float = quantity("length")
    alpha: float = quantity("angle")
    qmin: float = quantity("angle")
    qmax: float = quantity("angle")


@dataclass(frozen=True)
class DHLink:
    mass: float = quantity("mass", gt(0))
    volume: float = quantity("volume", ge(0))
    diameter: float = quantity("length", gt(0))


@dataclass(frozen=True)
class DHTool:
    length: float = quantity("length", ge(0))


@dataclass(frozen=True)
class ChainJoint:
    """A revolute joint in URDF's terms: origin in the parent's frame (xyz, then fixed-axis rpy), axis, limits."""

    x: float = quantity("length")
    y: float = quantity("length")
    z: float = quantity("length")
    roll: float = quantity("angle")
    pitch: float = quantity("angle")
    yaw: float = quantity("angle")
    axis: tuple[float, ...] = quantity("1", n=3)
    qmin: float = quantity("angle")
    qmax: float = quantity("angle")


@dataclass(frozen=True)
class ChainTool:
    x: float = quantity("length")
    y: float = quantity("length")
    z: float = quantity("length")


def _chain_link_cls(drag: bool, cd: bool) -> type:
    fields = [
        ("mass", float, quantity("mass", gt(0))),
        ("com", tuple[float, ...], quantity("length", n=3)),
        ("inertia", tuple[float, ...], quantity("inertia", n=6)),
        ("volume", float, quantity("volume", ge(0))),
        ("cob", tuple[float, ...], quantity("length", n=3)),
    ]
    if drag:
        fields += [("drag_diameter", float, quantity("length", gt(0))),
                   ("drag_from", tuple[float, ...], quantity("length", n=3)),
                   ("drag_to", tuple[float, ...], quantity("length", n=3))]
    if cd:
        fields.append(("Cd", float, quantity("1", ge(0))))
    return dataclasses.make_dataclass(f"ChainLink{'D' if drag else ''}{'C' if cd else ''}", fields, frozen=True)


def _mount_cls(rpy: bool) -> type:
    fields = [(k, float, quantity("length")) for k in ("x", "y", "z")]
    if rpy:
        fields += [(k, float, quantity("angle")) for k in ("roll", "pitch", "yaw")]
    return dataclasses.make_dataclass("Mount", fields, frozen=True)


@dataclass(frozen=True)
class SystemInfo:
    name: str = config.setting()
    description: str = config.setting(default="")


_SCHEMAS: dict[Structure, type] = {}


def schema_for(s: Structure) -> type:
    """The strict schema (a frozen dataclass of sections) of files of structure ``s``.

    Leaf order = the order of the parameter vector: env, vehicle, hydro (file order), thrusters, arm
    (mount, tool, joints, links, stow), payload (with an arm only).
    """
    cls = _SCHEMAS.get(s)
    if cls is not None:
        return cls
    hydro = dataclasses.make_dataclass("Hydro", [(t.name, float, quantity("per_rho")) for t in s.hydro], frozen=True)
    if s.thrusters is None:
        thr: type = HaidouThrusters
    else:
        dyn = s.thruster_dynamics or (None,) * len(s.thrusters)
        units = [s.thruster_map(d.map).unit if d is not None else "1" for d in dyn]
        tf = [(n, _thruster_cls(d, u), config.setting()) for n, d, u in zip(s.thrusters, dyn, units)]
        if s.thruster_maps:
            maps = dataclasses.make_dataclass("Maps", [(m.name, _map_cls(m), config.setting()) for m in s.thruster_maps],
                                              frozen=True)
            tf.append(("map", maps, config.setting()))
        thr = dataclasses.make_dataclass("Thrusters", tf, frozen=True)
    fields: list = [("env", Env if s.env_cd else EnvNoArm, config.setting()), ("vehicle", _vehicle_cls(s.buoyancy), config.setting()),
                    ("hydro", hydro, config.setting()), ("thrusters", thr, config.setting())]
    if s.n_joints:
        n = s.n_joints
        if s.arm == "dh":
            tool, joint = DHTool, DHJoint
            links = [DHLink] * n
        else:
            tool, joint = ChainTool, ChainJoint
            links = [_chain_link_cls(s.link_drag[i], s.link_cd[i]) for i in range(n)]
        stow = dataclasses.make_dataclass("Stow", [(f"q{i}", float, quantity("angle")) for i in range(1, n + 1)],
                                          frozen=True)
        arm = dataclasses.make_dataclass(
            "Arm",
            [("mount", _mount_cls(s.mount_rpy), config.setting()), ("tool", tool, config.setting())]
            + [(f"joint{i}", joint, config.setting()) for i in range(1, n + 1)]
            + [(f"link{i}", links[i - 1], config.setting()) for i in range(1, n + 1)]
            + [("stow", stow, config.setting())],
            frozen=True)
        fields.append(("arm", arm, config.setting()))
        fields.append(("payload", Payload, config.setting()))  # a point mass at the tool point
    cls = dataclasses.make_dataclass("SystemFile", fields, frozen=True)
    _SCHEMAS[s] = cls
    return cls


def file_doc(doc: dict) -> dict:
    """The document as the schema reads it: ``[system]``, ``[defaults]``, ``hydro.coriolis_added_mass`` and
    ``arm.trim`` (not numbers) removed, a thruster list keyed by name."""
    out = {k: v for k, v in doc.items() if k not in ("system", "defaults")}
    if isinstance(out.get("hydro"), dict) and "coriolis_added_mass" in out["hydro"]:
        out["hydro"] = {k: v for k, v in out["hydro"].items() if k != "coriolis_added_mass"}
    if isinstance(out.get("arm"), dict) and "trim" in out["arm"]:
        out["arm"] = {k: v for k, v in out["arm"].items() if k != "trim"}
    thr = out.get("thrusters")
    if isinstance(thr, dict) and isinstance(thr.get("unit"), list):
        listed = {u["name"]: {k: v for k, v in u.items() if k not in ("name", "map")} for u in thr["unit"]}
        if isinstance(thr.get("map"), dict):  # the maps' strings (table file, command unit) are structure
            listed["map"] = {n: {k: v for k, v in m.items() if k not in ("table", "command_unit")}
                             if isinstance(m, dict) else m for n, m in thr["map"].items()}
        out["thrusters"] = listed
    return out


def expand(key: str, value: Any) -> list[tuple[str, float]]:
    """A leaf's parameters: a scalar as itself, a vector as ``key.<element label>``."""
    if isinstance(value, tuple):
        labels = element_labels(key, len(value))
        return [(f"{key}.{lab}", float(x)) for lab, x in zip(labels, value)]
    return [(key, float(value))]


def rel_path(base: str | Path, name: str) -> Path:
    """A file named by a system file, relative to that file's folder."""
    p = Path(name)
    return p if p.is_absolute() else Path(base).parent / p

