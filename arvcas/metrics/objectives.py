"""Objectives and constraints of a study as objects, computed inside the compiled run (docs/objectives.md).

An :class:`Objective` has a name, a unit, a description, the accumulators it needs from the run
(:class:`arvcas.sim.accumulate.Accumulator`: sums and maxima the compiled run carries, so a study never
needs a trace) and a method that turns one draw's run outputs into its value per run (``values``) and,
for constraints, into the elements a constraint bounds (``elements``, default the value itself;
``peak_thrust``: each thruster's forward and reverse peak, so ``peak_thrust <= 0.8 * limit`` holds
thruster by thruster). The paper's two (``chat``, ``rmse``) need no accumulator: they are the run's
own outputs.

The registry is that of the controllers (:mod:`arvcas.controllers.base`): the built-in objectives,
those a plugin defines (an entry point of the group ``arvcas.objectives``, a ``--plugin`` file or
module, a study's ``[study] plugins``) and those :func:`register` is given. A study names 2 to 4 of
them and any constraints (:func:`parse_constraint`: ``name <= number``, ``name <= factor * limit``,
``>=`` alike; parsed by a regular expression, never evaluated).
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas.util import plugins
from arvcas.metrics.indices import normalised_objectives
from arvcas.sim import scenario
from arvcas.sim.accumulate import Accumulator, event_times, width

__all__ = ["Objective", "ObjectiveError", "Context", "Constraint", "register", "get", "names", "available",
           "adopt", "parse_constraint", "accumulators_of", "origin", "GROUP", "DEFAULT_SETTLING_BAND"]

GROUP = "arvcas.objectives"
# the settling band of settling_time: |e| within it on every position (m) and attitude (rad) DOF
# (arvcas choice, docs/objectives.md: 2.5 % of the default [limits] e_position = 2 m, 10 % of e_attitude = 0.5 rad)
DEFAULT_SETTLING_BAND = (0.05, 0.05)


class ObjectiveError(ValueError):
    """One line: an unknown objective, a malformed constraint, a bad registration."""


@dataclass(frozen=True)
class Context:
    """What an objective's ``values`` may use besides the run's outputs: the scenario (``cfg``), the
    system's parameters (``params``), the per-DOF normalisation of CHAT and RMSE (``ref``: None for the
    paper's Table 3 AGSTA), the CHAT output the study uses (``chat``: ``"chat"`` or ``"chat_delivered"``)
    and where each accumulator's rows are in the output ``acc`` (``slices``: name -> slice)."""

    cfg: object
    params: object
    ref: tuple | None
    chat: str
    slices: dict

    def acc(self, out: dict, name: str) -> np.ndarray:
        """The rows (n, width) of accumulator ``name`` in one draw's outputs."""
        return np.asarray(out["acc"], dtype=float).reshape(len(out["ok"]), -1)[:, self.slices[name]]


class Objective:
    """A study objective (smaller is better). Subclass it (or instantiate it with keyword arguments) and
    give ``name`` (an identifier), ``unit``, ``description``, ``accumulators`` (what the compiled run
    must accumulate for it) and ``values(out, ctx) -> (n,)``; ``elements`` and ``limit`` for a
    constraint on more than its value (docs/objectives.md, "Writing an objective")."""

    name: str = ""
    unit: str = ""
    description: str = ""
    accumulators: tuple[Accumulator, ...] = ()
    # True when every element is >= 0 by construction: a constraint 'name <= negative' can never hold and
    # 'name >= 0 or less' always holds, so both are refused (parse_constraint)
    nonnegative: bool = False

    def __init__(self, **kw):
        for k, v in kw.items():
            if not hasattr(type(self), k):
                raise ObjectiveError(f"objective: unknown attribute {k!r}")
            setattr(self, k, v)

    def values(self, out: dict, ctx: Context) -> np.ndarray:
        """The objective of each run of one draw, (n,); ``out``: the run's outputs by name (``chat``,
        ``chat_delivered``, ``rmse`` (n, 6), ``ok``, ``t_fail`` (n,), ``acc`` (n, rows))."""
        raise NotImplementedError

    def elements(self, out: dict, ctx: Context) -> np.ndarray:
        """What a constraint on this objective bounds, (n, e): by default its value (e = 1)."""
        return np.asarray(self.values(out, ctx), dtype=float)[:, None]

    def limit(self, ctx: Context):
        """The ``limit`` a constraint may name (per element, or a number); None: it has none."""
        return None

    def identity(self) -> str:
        return f"{type(self).__module__}.{type(self).__qualname__}:{self.name}:" + \
            ",".join(a.identity() for a in self.accumulators)

    def __repr__(self) -> str:
        return f"<objective {self.name} [{self.unit}]>"


# ---- the built-in objectives ---------------------------------------------------------------------------


class _Chat(Objective):
    name, unit = "chat", "1"
    nonnegative = True
    description = "mean over the 6 DOF of CHAT (eq. 42) / the AGSTA's (docs/model.md §7): the paper's f_chat"

    def values(self, out, ctx):
        return np.array([normalised_objectives(c, r, ctx.ref)[0] for c, r in zip(out[ctx.chat], out["rmse"])])


class _Rmse(Objective):
    name, unit = "rmse", "1"
    nonnegative = True
    description = ("mean over the held DOFs (all 6; z, phi, theta, psi without a position sensor: docs/sensors.md) of "
                   "RMSE (eq. 43) / the AGSTA's (docs/model.md §7): the paper's f_rmse")

    def values(self, out, ctx):  # the DOFs the task holds (all six, or without a position fix four: docs/sensors.md)
        held = None if ctx.cfg is None else scenario.held_dofs(ctx.cfg)
        return np.array([normalised_objectives(c, r, ctx.ref, held)[1] for c, r in zip(out[ctx.chat], out["rmse"])])


def _lim(cfg) -> np.ndarray:
    return np.array([cfg.limits_e_position] * 3 + [cfg.limits_e_attitude] * 3)


class _Iae(Objective):
    name, unit = "iae", "s"
    nonnegative = True
    description = ("integrated absolute error: mean over the 6 DOF of h sum_k |e_k| / the DOF's [limits] bound "
                   "(e = the true pose minus the reference; elements: the per-DOF integrals, m s and rad s)")
    accumulators = (Accumulator("iae", "sum", 6, lambda v: v.h * ca.fabs(v.e)),)

    def elements(self, out, ctx):
        return ctx.acc(out, "iae")

    def values(self, out, ctx):
        return np.mean(ctx.acc(out, "iae") / _lim(ctx.cfg), axis=1)


class _Energy(Objective):
    name, unit = "energy", "N^1.5 s"
    nonnegative = True
    description = ("electrical energy proxy h sum_k sum_i |T_i|^1.5 (actuator-disk power ~ |T|^1.5; the T200 at "
                   "16 V draws 0.95 |T|^1.5 W forward, 1.31 |T|^1.5 W reverse within 17 % above 5 N: docs/objectives.md)")
    accumulators = (Accumulator("energy", "sum", 1, lambda v: v.h * ca.sum1(ca.fabs(v.thrust) ** 1.5)),)

    def values(self, out, ctx):
        return ctx.acc(out, "energy")[:, 0]


class _PeakThrust(Objective):
    name, unit = "peak_thrust", "N"
    nonnegative = True
    description = ("largest thrust of any thruster over the run (elements: each thruster's forward peak, then its "
                   "reverse peak; limit: its u_max, then -u_min)")
    accumulators = (Accumulator("peak_fwd", "max", "thrusters", lambda v: ca.fmax(v.thrust, 0)),
                    Accumulator("peak_rev", "max", "thrusters", lambda v: ca.fmax(-v.thrust, 0)))

    def elements(self, out, ctx):
        return np.hstack([ctx.acc(out, "peak_fwd"), ctx.acc(out, "peak_rev")])

    def values(self, out, ctx):
        return self.elements(out, ctx).max(axis=1)

    def limit(self, ctx):
        from arvcas.model import thrusters
        from arvcas.system.params import view

        n = ctx.params.structure.n_thrusters
        lo, hi = (np.broadcast_to(np.array(ca.evalf(ca.DM(x)), dtype=float).ravel(), (n,))
                  for x in thrusters.limits(view(ca.DM(ctx.params.vector()), ctx.params.layout)))
        return np.concatenate([hi, -lo])


class _SaturationTime(Objective):
    name, unit = "saturation_time", "s"
    nonnegative = True
    description = "time during which the allocation asks any thruster for more than its limit (h x samples)"
    accumulators = (Accumulator("saturated", "sum", 1, lambda v: v.h * ca.if_else(
        ca.logic_or(ca.mmax(v.u_alloc - v.u_max) > 0, ca.mmax(v.u_min - v.u_alloc) > 0), 1, 0)),)

    def values(self, out, ctx):
        return ctx.acc(out, "saturated")[:, 0]


class _SettlingTime(Objective):
    """Settling time after each event of :func:`arvcas.sim.accumulate.event_times`: from the event to the
    end of the last sample before the next event (or the run's end) whose error leaves the band."""

    name, unit = "settling_time", "s"
    nonnegative = True
    description = ("largest settling time after an event (the start, each arm motion, each payload change): the "
                   "time until |e| stays within the band (0.05 m, 0.05 rad) up to the next event; elements: per event")

    def __init__(self, band=DEFAULT_SETTLING_BAND, **kw):
        super().__init__(**kw)
        self.band = (float(band[0]), float(band[1]))
        bp, ba = self.band

        def outside(v):
            ev = list(v.events) + [v.duration]
            out_ = ca.logic_or(ca.mmax(ca.fabs(v.e[0:3])) > bp, ca.mmax(ca.fabs(v.e[3:6])) > ba)
            return ca.vertcat(*[ca.if_else(ca.logic_and(ca.logic_and(v.t >= ev[j] - 1e-9, v.t < ev[j + 1] - 1e-9), out_),
                                           v.t + v.h - ev[j], 0) for j in range(len(ev) - 1)])

        self.accumulators = (Accumulator("settling", "max", "events", outside, key=f"band={bp!r},{ba!r}"),)

    def elements(self, out, ctx):
        return ctx.acc(out, "settling")

    def values(self, out, ctx):
        return ctx.acc(out, "settling").max(axis=1)


class _Excursion(Objective):
    name, unit = "excursion", "m"
    nonnegative = True
    description = "largest distance of the vehicle from its reference position, max_k |e_k[x, y, z]|"
    accumulators = (Accumulator("excursion", "max", 1, lambda v: ca.norm_2(v.e[0:3])),)

    def values(self, out, ctx):
        return ctx.acc(out, "excursion")[:, 0]


# ---- the registry ---------------------------------------------------------------------------------------

_LOCK = threading.RLock()
_REGISTRY: dict[str, Objective] = {}
_ORIGIN: dict[str, plugins.Plugin] = {}


def _validate(o) -> None:
    if not isinstance(o, Objective):
        raise ObjectiveError(f"register: expected an arvcas.metrics.objectives.Objective, got {type(o).__name__}")
    if not (isinstance(o.name, str) and o.name.isidentifier()):
        raise ObjectiveError(f"register: objective name {o.name!r} must be an identifier")
    if type(o).values is Objective.values:
        raise ObjectiveError(f"register: objective {o.name} defines no values(out, ctx)")
    for a in o.accumulators:
        if not isinstance(a, Accumulator):
            raise ObjectiveError(f"register: objective {o.name}: accumulators must be arvcas.sim.accumulate.Accumulator")


def register(o: Objective, replace: bool = False) -> Objective:
    """Add ``o`` to the registry (``replace=True`` to redefine a name); returns it."""
    _validate(o)
    origin_ = plugins.current()
    with _LOCK:
        if o.name in _REGISTRY and not replace and _REGISTRY[o.name] is not o:
            raise ObjectiveError(f"register: an objective named {o.name!r} exists (pass replace=True to redefine it)")
        _REGISTRY[o.name] = o
        if origin_ is not None:
            _ORIGIN.setdefault(o.name, origin_)
    return o


def names() -> tuple[str, ...]:
    """Registered objective names (entry points not loaded yet are not among them: :func:`available`)."""
    with _LOCK:
        return tuple(_REGISTRY)


def available() -> tuple[str, ...]:
    """Every objective name, the entry points of ``arvcas.objectives`` loaded."""
    plugins.load_group(GROUP)
    return names()


def get(name, settling_band=None) -> Objective:
    """The objective ``name`` (an Objective is returned as is); a name not registered is looked for among
    the entry points. ``settling_band``: (m, rad) for ``settling_time`` (default :data:`DEFAULT_SETTLING_BAND`)."""
    if isinstance(name, Objective):
        return name
    with _LOCK:
        o = _REGISTRY.get(name)
    if o is None:
        plugins.find(GROUP, name)
        with _LOCK:
            o = _REGISTRY.get(name)
        if o is None:
            plugins.load_group(GROUP)
            with _LOCK:
                o = _REGISTRY.get(name)
    if o is None:
        raise ObjectiveError(f"unknown objective {name!r} (allowed: {', '.join(names())})")
    if name == "settling_time" and settling_band is not None and tuple(settling_band) != o.band:
        return _SettlingTime(band=settling_band)
    return o


def call_objective(o: Objective, method: str, out: dict, ctx: Context, n: int) -> np.ndarray:
    """``o.values(out, ctx)`` (``method`` "values": shape (n,)) or ``o.elements(out, ctx)`` ("elements": (n, k),
    k >= 1) with what it returns checked: whatever the objective's code raises or returns (None, strings, a
    wrong shape) is one :class:`ObjectiveError` line naming the objective, its file (or plugin) and what
    was expected."""
    import inspect

    try:
        where = inspect.getsourcefile(type(o)) or type(o).__module__
    except (TypeError, OSError):
        where = type(o).__module__
    rec = origin(o.name)
    if rec.get("spec"):
        where = f"plugin {rec.get('kind', '')} {rec['spec']}".replace("  ", " ")
    what = f"objective {o.name!r} ({where}): {method}"
    try:
        got = getattr(o, method)(out, ctx)
    except ObjectiveError:
        raise
    except Exception as e:  # noqa: BLE001 - whatever the objective's code raises
        raise ObjectiveError(f"{what} raised {plugins.why(e, where if Path(str(where)).exists() else None)}") from None
    want = f"({n},)" if method == "values" else f"({n}, k)"
    try:
        a = np.asarray(got, dtype=float) if not isinstance(got, (str, bytes)) and got is not None else None
    except (TypeError, ValueError):
        a = None
    if a is None or np.asarray(got).dtype.kind == "b" or \
            (a.shape != (n,) if method == "values" else (a.ndim != 2 or a.shape[0] != n or a.shape[1] < 1)):
        shape = getattr(a, "shape", None)
        text = f"shape {shape}" if shape is not None else " ".join(repr(got).split())[:60]
        raise ObjectiveError(f"{what} returned {type(got).__name__} {text}; expected an array of shape {want} "
                             f"(one value per run)")
    return a


def origin(name: str) -> dict:
    """Where an objective from outside the package came from (empty for a built-in one)."""
    with _LOCK:
        p = _ORIGIN.get(name)
    if p is None:
        return {}
    files = plugins.source_files(p.module)
    return {**p.record(), "digest": plugins.digest(files)}


def adopt(obj) -> list[str]:
    """Register the objectives ``obj`` defines (the registry's side of :mod:`arvcas.util.plugins`): an
    Objective instance, an Objective subclass with a name (instantiated), or a module's such objects."""
    import inspect

    items = [obj] if not inspect.ismodule(obj) else [v for v in vars(obj).values()
                                                     if isinstance(v, Objective) or (inspect.isclass(v) and issubclass(v, Objective)
                                                                                     and v.__module__ == obj.__name__)]
    done = []
    for v in items:
        if inspect.isclass(v):
            if not (issubclass(v, Objective) and v.name):
                continue
            v = v()
        if isinstance(v, Objective):
            register(v, replace=True)
            done.append(v.name)
    return done


for _o in (_Chat(), _Rmse(), _Iae(), _Energy(), _PeakThrust(), _SaturationTime(), _SettlingTime(), _Excursion()):
    register(_o)
plugins.add_registry(GROUP, adopt)


def accumulators_of(objectives) -> tuple[Accumulator, ...]:
    """The accumulators the objectives need, each once (by name; two objectives may share one), in order."""
    out: dict[str, Accumulator] = {}
    for o in objectives:
        for a in o.accumulators:
            if a.name in out and out[a.name].identity() != a.identity():
                raise ObjectiveError(f"objective {o.name}: accumulator {a.name!r} is defined differently by another "
                                     f"objective of the study")
            out.setdefault(a.name, a)
    return tuple(out.values())


def slices(accs, n_thrusters: int, cfg) -> dict:
    """Where each accumulator's rows are in the run's output ``acc``."""
    n_ev, i, out = len(event_times(cfg)), 0, {}
    for a in accs:
        w = width(a, n_thrusters, n_ev)
        out[a.name] = slice(i, i + w)
        i += w
    return out


# ---- constraints ----------------------------------------------------------------------------------------

_NUM = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_CONSTRAINT = re.compile(rf"^\s*([A-Za-z_]\w*)\s*(<=|>=)\s*(?:({_NUM})|(?:({_NUM})\s*\*\s*)?limit(?:\s*\*\s*({_NUM}))?)\s*$")
FORMS = "'name <= number', 'name <= factor * limit' or 'name <= limit' (or >=)"


@dataclass(frozen=True)
class Constraint:
    """``objective op rhs``: ``rhs`` a number, or ``factor`` times the objective's ``limit``."""

    text: str
    objective: str
    op: str  # "<=" or ">="
    number: float | None = None
    factor: float | None = None

    def rhs(self, o: Objective, ctx: Context):
        if self.number is not None:
            return self.number
        lim = o.limit(ctx)
        return self.factor * np.asarray(lim, dtype=float)

    def violation(self, o: Objective, out: dict, ctx: Context) -> np.ndarray:
        """pymoo's G (<= 0 satisfied) of each run of one draw, (n,): the largest over the elements of
        (lhs - rhs) / |rhs| (``>=``: rhs - lhs), the difference alone where rhs is 0."""
        lhs = call_objective(o, "elements", out, ctx, len(out["ok"]))
        rhs = np.broadcast_to(self.rhs(o, ctx), (lhs.shape[1],))
        d = lhs - rhs if self.op == "<=" else rhs - lhs
        scale = np.where(rhs != 0, np.abs(rhs), 1.0)
        return (d / scale).max(axis=1)


def parse_constraint(text: str, where: str = "constraint", settling_band=None) -> Constraint:
    """A constraint from its text (:data:`FORMS`), checked against the registry: one-line
    :class:`ObjectiveError` naming ``where`` (may be empty) and what is allowed."""
    pre = f"{where}: " if where else ""
    if not isinstance(text, str):
        raise ObjectiveError(f"{pre}expected a string of the form {FORMS}, got {type(text).__name__}")
    m = _CONSTRAINT.match(text)
    if m is None:
        raise ObjectiveError(f"{pre}{text!r} is not a constraint (allowed forms: {FORMS}, e.g. "
                             f"'peak_thrust <= 0.8 * limit')")
    name, op, num, f1, f2 = m.groups()
    if f1 is not None and f2 is not None:
        raise ObjectiveError(f"{pre}{text!r}: one factor of limit (allowed forms: {FORMS})")
    try:
        o = get(name, settling_band)
    except ObjectiveError:
        raise ObjectiveError(f"{pre}{text!r}: unknown objective {name!r} (allowed: {', '.join(available())})") from None
    if num is None:
        factor = float(f1 if f1 is not None else f2 if f2 is not None else 1.0)
        if type(o).limit is Objective.limit:
            with_limit = [n for n in available() if type(get(n)).limit is not Objective.limit]
            raise ObjectiveError(f"{pre}{text!r}: objective {name} has no limit (objectives with one: "
                                 f"{', '.join(with_limit)}); give a number")
        if not np.isfinite(factor):
            raise ObjectiveError(f"{pre}{text!r}: the factor must be finite")
        # the limit of a never-negative objective is itself >= 0 (peak_thrust's: u_max and -u_min), so the
        # factor's sign decides as a number's does
        _sign_check(o, op, factor, text, pre, "a factor")
        return Constraint(text=text, objective=name, op=op, factor=factor)
    if not np.isfinite(float(num)):
        raise ObjectiveError(f"{pre}{text!r}: the bound must be finite")
    _sign_check(o, op, float(num), text, pre, "a bound")
    return Constraint(text=text, objective=name, op=op, number=float(num))


def _sign_check(o: Objective, op: str, value: float, text: str, pre: str, what: str) -> None:
    """A constraint on a never-negative objective that can never hold (``<=`` below 0) or always holds
    (``>=`` at or below 0): one line."""
    if o.nonnegative and op == "<=" and value < 0:
        raise ObjectiveError(f"{pre}{text!r} can never hold: {o.name} is never negative (give {what} >= 0)")
    if o.nonnegative and op == ">=" and value <= 0:
        raise ObjectiveError(f"{pre}{text!r} always holds: {o.name} is never negative (give {what} > 0)")
