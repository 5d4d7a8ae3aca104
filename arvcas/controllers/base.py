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
from typing import Any, Callable

__all__ = ["Gain", "Controller", "ControllerError", "register", "get", "names", "unregister"]

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


_REGISTRY: dict[str, Controller] = {}
_LOCK = threading.Lock()


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


def register(c: Controller, replace: bool = False) -> Controller:
    """Add ``c`` to the registry (``replace=True`` to redefine a name); returns it."""
    _validate(c)
    with _LOCK:
        if c.name in _REGISTRY and not replace and _REGISTRY[c.name] is not c:
            raise ControllerError(f"register: a controller named {c.name!r} exists (pass replace=True to redefine it)")
        _REGISTRY[c.name] = c
    return c


def unregister(name: str) -> None:
    with _LOCK:
        _REGISTRY.pop(name, None)


def names() -> tuple[str, ...]:
    """Registered controller names, in registration order."""
    with _LOCK:
        return tuple(_REGISTRY)


def get(name) -> Controller:
    """The controller ``name`` (a Controller instance is returned as is)."""
    if isinstance(name, Controller):
        return name
    with _LOCK:
        c = _REGISTRY.get(name) if isinstance(name, str) else None
        if c is None:
            close = difflib.get_close_matches(str(name), list(_REGISTRY), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise ControllerError(f"controller: unknown '{name}'{hint} (allowed: {', '.join(_REGISTRY)})")
        return c
