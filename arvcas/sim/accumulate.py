"""Accumulators: per-sample quantities summed or maximised inside the compiled run (docs/objectives.md).

An :class:`Accumulator` names a quantity of one controller sample (a CasADi expression of the
:class:`SampleView`) and how the run folds it over the samples k = 0 .. N-1 (the N intervals
``[t_k, t_k + h)``, the samples RMSE covers, eq. 43): ``"sum"`` (the sum of the values; an integral
over the run is the value times ``h``) or ``"max"`` (the largest value; values must be >= 0, the fold
starts at 0). The run carries one state slot per row of each accumulator and returns them all as its
output ``acc`` (stacked in the order given), so a study reads them without a trace. A run built
without accumulators is the run of before: same state, same outputs, same generated code.

The objectives of :mod:`arvcas.metrics.objectives` are built on these; a user objective declares its
own (docs/objectives.md, "Writing an objective").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

__all__ = ["Accumulator", "SampleView", "KINDS", "event_times", "width"]

KINDS = ("sum", "max")


@dataclass(frozen=True)
class Accumulator:
    """One accumulated quantity. ``name``: unique in a run (an identifier); ``kind``: ``"sum"`` or
    ``"max"``; ``width``: rows (an int, ``"thrusters"``: one per thruster, ``"events"``: one per event of
    :func:`event_times`); ``value(view)``: the sample's value, a column of ``width`` rows (CasADi SX);
    ``key``: text naming anything else that shapes its graph (a band, a threshold), part of the compiled
    run's cache key with ``name`` and the source of ``value``'s module."""

    name: str
    kind: str
    width: int | str
    value: Callable[[Any], Any]
    key: str = ""

    def __post_init__(self):
        if not (isinstance(self.name, str) and self.name.isidentifier()):
            raise ValueError(f"accumulator name {self.name!r}: must be an identifier")
        if self.kind not in KINDS:
            raise ValueError(f"accumulator {self.name}: kind {self.kind!r} (allowed: {', '.join(KINDS)})")
        if not (self.width in ("thrusters", "events") or (isinstance(self.width, int) and self.width >= 1)):
            raise ValueError(f"accumulator {self.name}: width {self.width!r} (an int >= 1, 'thrusters' or 'events')")

    def identity(self) -> str:
        v = self.value
        where = f"{getattr(v, '__module__', '')}.{getattr(v, '__qualname__', type(v).__name__)}"
        return f"{self.name}:{self.kind}:{self.width}:{where}:{self.key}"


def width(acc: Accumulator, n_thrusters: int, n_events: int) -> int:
    """The rows of ``acc`` for a system of ``n_thrusters`` and a scenario of ``n_events`` events."""
    return {"thrusters": n_thrusters, "events": n_events}.get(acc.width, acc.width)


class SampleView:
    """What an accumulator's ``value`` sees at sample k (CasADi SX; {n} unless stated):

    ``t`` (s), ``h`` (s, the sample period), ``e`` (6: the true pose minus the reference ``eta_ref``, the
    error RMSE is computed on, m and rad), ``eta``, ``nu`` (the true state; nu in {b}), ``eta_ref``;
    ``tau_cmd`` (6, the controller's commanded wrench, {b}); ``tau_del`` (6, the thrusters' wrench acting
    at t_k, {b}); ``thrust`` (per thruster, N: the thrust over the interval: the saturated command held
    over it, or with thruster dynamics the rotor's delivered thrust at t_k); ``u_alloc`` (per thruster,
    N: the allocation before saturation); ``u_min``, ``u_max`` (per thruster, N: the limits);
    ``events`` (the scenario's event times, s, :func:`event_times`); ``duration`` (s); ``P`` (the
    parameter view)."""

    def __init__(self, **kw):
        self.__dict__.update(kw)


def event_times(cfg) -> tuple[float, ...]:
    """The times after which a settling time is measured (s, sorted, within ``[0, duration)``): the
    run's start, the start of every arm motion (the paper's reach and return, or each moving
    ``[[arm.waypoint]]`` segment) and every payload change (the paper's grasp, or ``[[payload.event]]``)."""
    T = cfg.time_duration
    ts = [0.0]
    if cfg.arm_waypoint:
        wps = cfg.arm_waypoint
        ts += [wps[j - 1].t for j in range(1, len(wps)) if tuple(wps[j].q) != tuple(wps[j - 1].q)]
    elif cfg.arm_hold_until is not None:
        ts += [cfg.arm_hold_until, cfg.arm_return_start]
    if cfg.payload_event:
        ts += [e.t for e in cfg.payload_event]
    elif cfg.arm_payload_on is not None:
        ts.append(cfg.arm_payload_on)
    return tuple(sorted({float(t) for t in ts if t is not None and 0.0 <= t < T}))
