"""What a controller is, and the one registry of them.

A :class:`Controller` declares

* ``gains``: its per-DOF gain columns (:class:`Gain`: name, unit, meaning, a limit that depends on the
  sampling period where stability needs one); the flat gain vector is DOF by DOF (x .. psi), each DOF
  in this column order; the system's defaults come from the system's gain table
  (``arvcas/data/gains.toml``, block :attr:`Controller.defaults_block`);
* ``state``: its per-run state (name, width), with :meth:`Controller.initial` the values at the
  first sample (they may depend on the first estimate);
* :meth:`Controller.step`: one controller sample, from the step's context (the EKF estimate, the
  reference and the errors, the nominal inertia, the model parameters; see
  :class:`arvcas.sim.closedloop.StepContext`) and its state to the commanded body wrench ``tau_v``
  and the next state;
* ``signals``: the extra traced signals (:class:`arvcas.sim.signals.Signal`), computed from the
  context extended by whatever the step put in ``ctx.out``.

The closed loop (:mod:`arvcas.sim.closedloop`) does everything around it the same way for every
controller: sensors and EKF, the reference, allocation and saturation, the plant, the metrics.

:func:`register` adds a controller (a user's own, from outside the package, too); :func:`get` finds one
by name. Nothing dispatches on controller names anywhere else.
"""

from __future__ import annotations

import difflib
import inspect
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from arvcas.util import plugins

__all__ = ["Gain", "Controller", "ControllerError", "call_law", "register", "get", "names", "available", "unregister", "adopt",
           "origin", "provenance", "describe_provenance", "GROUP", "aliases", "canonical", "accepted"]

DOFS = ("x", "y", "z", "phi", "theta", "psi")


class ControllerError(ValueError):
    """One-line error about a controller name or definition."""


@dataclass(frozen=True)
class Gain:
    """One per-DOF gain column.

    ``upper_of_h``: where the discrete law is stable only below a limit that depends on the sampling
    period h, that (exclusive) limit as a function of h (e.g. the explicit RESO: omega < 2 / h).
    Every gain is a positive number; tuning searches it on a log scale.
    """

    name: str
    unit: str
    description: str
    upper_of_h: Callable[[float], float] | None = None


class Controller:
    """Base class of a control law (see the module docstring). Subclasses set the class attributes
    and implement :meth:`initial` and :meth:`step`; instances are stateless descriptions."""

    name: str = ""
    # other names of this law, accepted wherever a law is named and resolved to ``name`` (which files, directories
    # and compiled functions keep); a class's own, not inherited (a subclass is another law)
    aliases: tuple[str, ...] = ()
    label: str = ""  # the name in figures and tables (default: name)
    color: str = ""  # its matplotlib colour in figures (default: the colour cycle)
    description: str = ""
    gains: tuple[Gain, ...] = ()
    defaults_block: str = ""  # block of the system's gain table holding the default gains
    state: tuple[tuple[str, int], ...] = ()
    signals: tuple = ()

    # -- the law ---------------------------------------------------------------------------------
    def initial(self, ctx, G: dict) -> dict[str, Any]:
        """State at the first sample (name -> expression of the width declared in :attr:`state`)."""
        raise NotImplementedError

    def step(self, ctx, G: dict, x: dict) -> tuple[Any, dict]:
        """One sample: ``(tau_v (6, body wrench at the COB), next state)``.

        ``G``: column name -> 6-vector of this run's gains (one entry per DOF); ``x``: this sample's
        state (name -> expression). Values needed by :attr:`signals` go in ``ctx.out``.
        """
        raise NotImplementedError

    # -- description -------------------------------------------------------------------------------
    def columns(self) -> list[str]:
        return [g.name for g in self.gains]

    def source_files(self) -> list[str]:
        """Files whose code defines this controller (they key the compile cache)."""
        out = []
        for cls in type(self).__mro__:
            if cls is object:
                continue
            try:
                out.append(inspect.getsourcefile(cls))
            except TypeError:  # built in
                continue
        return sorted({f for f in out if f})

    def own_source_files(self) -> list[str]:
        """The files of this law's code outside the package (empty for the package's own laws): for each
        class of its hierarchy defined elsewhere, its module's file, or every ``.py`` file of the
        top-level package it is in (:func:`arvcas.util.plugins.source_files`). They key the compile cache."""
        pkg = str(Path(__file__).resolve().parents[1])
        out = set()
        for cls in type(self).__mro__:
            if cls is object or cls.__module__ == "arvcas" or cls.__module__.startswith("arvcas."):
                continue
            files = plugins.source_files(cls.__module__)
            if not files:
                try:
                    f = inspect.getsourcefile(cls)
                except TypeError:  # built in
                    f = None
                files = [f] if f else []
            out.update(f for f in files if not str(Path(f).resolve()).startswith(pkg))
        return sorted(out)

    def source_digest(self) -> str:
        """sha256 of :meth:`own_source_files` (what a front records of a law defined outside the package)."""
        return plugins.digest(self.own_source_files())

    def identity(self) -> str:
        """A text that changes whenever the compiled law could: class, columns, state, signals."""
        cls = type(self)
        sig = ",".join(f"{s.name}:{s.width}" for s in self.signals)
        st = ",".join(f"{n}:{w}" for n, w in self.state)
        return f"{cls.__module__}.{cls.__qualname__}|{self.name}|{','.join(self.columns())}|{st}|{sig}|{self.options()}"

    def options(self) -> str:
        """Options of this instance that change its graph (part of :meth:`identity`)."""
        return ""

    def __repr__(self) -> str:
        return f"<controller {self.name}: {len(self.gains)} gains per DOF>"


# ---- calling a law: what its code returns, checked before anything is compiled --------------------------


def _where(law: Controller) -> str:
    """The law and the file (or plugin) its class comes from, for a one-line error."""
    p = origin(law.name)
    if p is not None:
        return f"controller {law.name!r} ({p.describe()})"
    try:
        f = inspect.getsourcefile(type(law))
    except (TypeError, OSError):
        f = None
    return f"controller {law.name!r} ({f or type(law).__module__})"


def _shown(v) -> str:
    text = " ".join(repr(v).split())
    return text if len(text) <= 60 else text[:57] + "..."


def _column(v, n: int):
    """``v`` as an (n, 1) CasADi column (a CasADi expression kept as it is), or None if it is not one."""
    import casadi as ca

    if isinstance(v, (ca.SX, ca.MX, ca.DM)):
        return v if v.shape == (n, 1) and _finite_if_constant(v) else None
    if v is None or isinstance(v, (str, bytes, bool, dict)):
        return None
    try:
        import numpy as np

        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return None
    if a.size != n or a.ndim > 2 or (a.ndim == 2 and a.shape[1] != 1) or not np.all(np.isfinite(a)):
        return None
    return ca.DM(a.reshape(n, 1))


def _finite_if_constant(v) -> bool:
    """A CasADi column's values are finite where they are known now (a DM, or an expression of no symbol):
    a NaN or inf constant would only show after the compile, as a run that fails."""
    import casadi as ca
    import numpy as np

    if not isinstance(v, ca.DM):
        if ca.symvar(v):
            return True
        v = ca.evalf(v)
    return bool(np.all(np.isfinite(np.asarray(v, dtype=float))))


def _what_is(v) -> str:
    shape = getattr(v, "shape", None)
    if shape is None:
        return f"{type(v).__name__} {_shown(v)}"
    bad = "" if not hasattr(v, "is_constant") or _finite_if_constant(v) else " with non-finite values"
    return f"{type(v).__name__} of shape {tuple(shape)}{bad}"


def _state(law: Controller, method: str, got) -> dict:
    """``got``, the law's state as ``method`` returned it, checked against :attr:`Controller.state`."""
    want = ", ".join(f"{n} ({w})" for n, w in law.state) or "no entries"
    if not isinstance(got, dict):
        raise ControllerError(f"{_where(law)}: {method} returned {_what_is(got)} as its state; expected a dict of "
                              f"the law's state: {want}")
    out = dict(got)
    for n, w in law.state:
        if n not in got:
            raise ControllerError(f"{_where(law)}: {method} returned no state entry {n!r}; expected a dict of the "
                                  f"law's state: {want}")
        col = _column(got[n], w)
        if col is None:
            raise ControllerError(f"{_where(law)}: {method} returned {_what_is(got[n])} for the state entry {n!r}; "
                                  f"expected a {w}-vector (a CasADi expression or finite numbers)")
        out[n] = col
    return out


def call_law(law: Controller, method: str, *args):
    """``law.initial(ctx, G)`` (``method`` "initial") or ``law.step(ctx, G, x)`` ("step"), with what it returns
    checked: the state a dict of the widths of :attr:`Controller.state`, ``tau_v`` a 6-vector. Whatever its
    code raises, or a wrong return, is one :class:`ControllerError` line naming the law's file (or plugin),
    the method, what it returned and what was expected; raised while the graph is built, before any compile."""
    try:
        got = getattr(law, method)(*args)
    except ControllerError:
        raise
    except Exception as e:  # noqa: BLE001 - whatever the law's code raises
        try:
            path = inspect.getsourcefile(type(law))
        except (TypeError, OSError):
            path = None
        raise ControllerError(f"{_where(law)}: {method} raised {plugins.why(e, path)}") from None
    if method == "initial":
        return _state(law, method, got)
    if not (isinstance(got, tuple) and len(got) == 2):
        raise ControllerError(f"{_where(law)}: step returned {_what_is(got)}; expected a pair (tau_v, next_state): "
                              f"tau_v the commanded body wrench (a 6-vector), next_state a dict of the law's state")
    tau = _column(got[0], 6)
    if tau is None:
        raise ControllerError(f"{_where(law)}: step returned {_what_is(got[0])} as tau_v; expected the commanded "
                              f"body wrench, a 6-vector (a CasADi expression or 6 finite numbers)")
    return tau, _state(law, method, got[1])


_REGISTRY: dict[str, Controller] = {}
_ALIASES: dict[str, str] = {}  # alias -> the registered name it stands for
_ORIGIN: dict[str, object] = {}  # name -> the plugin (arvcas.util.plugins.Plugin) that registered it
_LOCK = threading.Lock()
GROUP = "arvcas.controllers"  # the entry-point group of controllers (docs/plugins.md)


def _validate(c: Controller) -> None:
    from arvcas.sim.signals import COMMON, check_signals

    if not isinstance(c, Controller):
        raise ControllerError(f"register: expected an arvcas.controllers.Controller instance, got {type(c).__name__}")
    if not isinstance(c.name, str) or not c.name.isidentifier():
        raise ControllerError(f"register: controller name {c.name!r} must be an identifier")
    cols = c.columns()
    if not cols or len(set(cols)) != len(cols) or not all(isinstance(n, str) and n.isidentifier() for n in cols):
        raise ControllerError(f"controller {c.name}: gain columns must be unique identifiers, got {cols}")
    if not c.defaults_block:
        raise ControllerError(f"controller {c.name}: defaults_block names no block of the gain table")
    for n, w in c.state:
        if not (isinstance(n, str) and n.isidentifier() and isinstance(w, int) and w >= 1):
            raise ControllerError(f"controller {c.name}: state entries must be (identifier, width >= 1), got {(n, w)}")
    try:
        check_signals(COMMON + tuple(c.signals))
    except ValueError as e:
        raise ControllerError(f"controller {c.name}: {e}") from None
    als = _own_aliases(c)
    if not all(isinstance(a, str) and a.isidentifier() and a != c.name for a in als) or len(set(als)) != len(als):
        raise ControllerError(f"controller {c.name}: aliases must be distinct identifiers other than its name, got "
                              f"{als!r}")


def _own_aliases(c: Controller) -> tuple[str, ...]:
    """The aliases ``c``'s own class declares (a subclass does not inherit its parent's: it is another law)."""
    return tuple(type(c).__dict__.get("aliases", ()))


def register(c: Controller, replace: bool = False) -> Controller:
    """Add ``c`` to the registry (``replace=True`` to redefine a name), with its :attr:`Controller.aliases`;
    returns it. A name or alias already standing for another law is refused."""
    _validate(c)
    origin = plugins.current()  # a plugin's code registering (its import, or the registry adopting it)
    with _LOCK:
        if c.name in _REGISTRY and not replace and _REGISTRY[c.name] is not c:
            raise ControllerError(f"register: a controller named {c.name!r} exists (pass replace=True to redefine it)")
        if c.name in _ALIASES:
            raise ControllerError(f"register: {c.name!r} is an alias of controller {_ALIASES[c.name]!r}")
        for a in _own_aliases(c):
            taken = a if a in _REGISTRY else _ALIASES.get(a, c.name)
            if taken != c.name:
                raise ControllerError(f"register: controller {c.name}: its alias {a!r} already names controller "
                                      f"{taken!r}")
        for a in [a for a, n in _ALIASES.items() if n == c.name]:
            del _ALIASES[a]
        _ALIASES.update({a: c.name for a in _own_aliases(c)})
        _REGISTRY[c.name] = c
        if origin is not None:
            _ORIGIN[c.name] = origin
        else:
            _ORIGIN.pop(c.name, None)
    return c


def unregister(name: str) -> None:
    with _LOCK:
        _REGISTRY.pop(name, None)
        _ORIGIN.pop(name, None)
        for a in [a for a, n in _ALIASES.items() if n == name]:
            del _ALIASES[a]


def aliases() -> dict[str, str]:
    """Alias -> the registered controller name it stands for."""
    with _LOCK:
        return dict(_ALIASES)


def canonical(name):
    """The registered name an alias stands for; anything else unchanged (a name, an unknown name, a Controller)."""
    if not isinstance(name, str):
        return name
    with _LOCK:
        return _ALIASES.get(name, name)


def accepted() -> tuple[str, ...]:
    """Every name a law may be given by: the registered names, then the aliases."""
    with _LOCK:
        return tuple(_REGISTRY) + tuple(_ALIASES)


def names() -> tuple[str, ...]:
    """Registered controller names, in registration order (entry points not loaded yet are not
    among them: :func:`available`)."""
    with _LOCK:
        return tuple(_REGISTRY)


def available() -> tuple[tuple[str, ...], list[str]]:
    """Every controller: the registered ones after loading every entry point of the group
    ``arvcas.controllers``; and the one-line failures of the plugins that did not load."""
    failed = plugins.load_group(GROUP)
    return names(), failed


def get(name) -> Controller:
    """The controller ``name`` (a Controller instance is returned as is). A name not registered is looked
    for among the entry points of the group ``arvcas.controllers`` (those of that name first, then all)."""
    if isinstance(name, Controller):
        return name
    name = canonical(name)
    with _LOCK:
        c = _REGISTRY.get(name) if isinstance(name, str) else None
    if c is None and isinstance(name, str):
        plugins.find(GROUP, name)  # an entry point of that name: loaded, or a one-line PluginError
        with _LOCK:
            c = _REGISTRY.get(name)
        failed = plugins.load_group(GROUP) if c is None else []
        with _LOCK:
            c = _REGISTRY.get(name)
    if c is None:
        with _LOCK:
            known = list(_REGISTRY)
        close = difflib.get_close_matches(str(name), known + list(_ALIASES), n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        broken = f"; plugins that failed to load: {' | '.join(failed)}" if isinstance(name, str) and failed else ""
        raise ControllerError(f"controller: unknown '{name}'{hint} (allowed: {', '.join(known)}; a controller of "
                              f"your own: --plugin FILE.py or an entry point, docs/plugins.md){broken}")
    return c


# ---- plugins: what a plugin defines, and where a law came from ---------------------------------------


def adopt(obj) -> list[str]:
    """Register the controllers ``obj`` defines (the registry's side of :mod:`arvcas.util.plugins`): a
    Controller instance, a Controller subclass (instantiated), or a module: the subclasses with a
    ``name`` defined in it (or, for a package, in its submodules) and the instances it holds. A law the
    module registered itself is kept. Returns the names registered."""
    import types

    if isinstance(obj, types.ModuleType):
        found, mod = [], obj.__name__
        for v in list(vars(obj).values()):
            if isinstance(v, Controller) or (isinstance(v, type) and issubclass(v, Controller) and v is not Controller
                                             and (v.__module__ == mod or v.__module__.startswith(mod + "."))
                                             and v.name):
                found.append(v)
        out = []
        for v in found:
            out += adopt(v)
        return out
    if isinstance(obj, type) and issubclass(obj, Controller):
        with _LOCK:
            have = _REGISTRY.get(obj.name)
        if have is not None and type(have) is obj:
            _claim(obj.name)
            return [obj.name]
        obj = obj()
    if isinstance(obj, Controller):
        with _LOCK:
            have = _REGISTRY.get(obj.name)
        if have is obj or (have is not None and type(have) is type(obj) and have.identity() == obj.identity()):
            _claim(obj.name)
            return [obj.name]
        register(obj)
        return [obj.name]
    raise ControllerError(f"expected a Controller subclass or instance, or a module defining them, got "
                          f"{type(obj).__name__}")


def _claim(name: str) -> None:
    origin = plugins.current()
    if origin is not None:
        with _LOCK:
            _ORIGIN.setdefault(name, origin)


def origin(name: str):
    """The plugin (:class:`arvcas.util.plugins.Plugin`) that registered controller ``name``, or None (built
    in, or registered from the user's own Python code)."""
    with _LOCK:
        return _ORIGIN.get(name)


def provenance(c) -> dict:
    """Where a law came from, for a front to record: empty for the package's own laws; else the
    controller's name and class, the digest of its own source files (what keys its compiled library),
    the files, and how to load it again (``kind``, ``spec``, ``entry_point``, ``distribution``: the
    plugin; kind "python" for a law registered from the user's own code)."""
    c = get(c)
    own = c.own_source_files()
    if not own:
        return {}
    cls = type(c)
    out = {"controller": c.name, "class": f"{cls.__module__}.{cls.__qualname__}",
           "digest": plugins.digest(own), "files": own}
    p = origin(c.name)
    if p is not None:
        out |= p.record()
    else:
        script = cls.__module__ == "__main__"
        out |= {"kind": "python", "spec": "" if script else own[0] if len(own) == 1 else cls.__module__,
                "module": cls.__module__, "entry_point": "", "distribution": ""}
    return out


def describe_provenance(rec: dict) -> tuple[str, str]:
    """``(where it came from, how to load it again)`` of a :func:`provenance` record, for one-line messages."""
    kind, spec = rec.get("kind", ""), rec.get("spec", "")
    if kind == "entry point":
        p = plugins.Plugin(kind, spec, rec.get("module", ""), rec.get("entry_point", ""), rec.get("distribution", ""))
        return p.describe(), p.hint()
    if kind in ("file", "module"):
        return f"plugin {kind} {spec}", f"load it with --plugin {spec}"
    files = rec.get("files") or []
    where = f"class {rec.get('class', '?')} registered from Python" + (f" ({files[0]})" if files else "")
    return where, (f"load it with --plugin {spec}" if spec else "register it from Python before this command")


plugins.add_registry(GROUP, adopt)
