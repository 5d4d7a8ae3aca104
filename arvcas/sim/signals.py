"""The signal table: every traced quantity of a closed-loop run, described once.

A :class:`Signal` names a per-sample quantity, its width, unit, frame, column names and meaning, and
says how the compiled step computes it (``value``: a function of the step's context, see
:class:`arvcas.sim.closedloop.StepContext`). From this one table come

* the trace the compiled run returns (one row block per signal, in table order),
* the series of a :class:`arvcas.sim.simulation.Result` (``result.eta``, ``result["eta"]``),
* the HDF5 datasets of a result file and their ``units``/``frame``/``columns``/``description``
  attributes (:mod:`arvcas.io.results`),
* plot axis labels (:func:`label`).

:data:`COMMON` holds the signals of every run (plant, estimate, reference, command); a controller
adds its own (:attr:`arvcas.controllers.Controller.signals`, e.g. the sliding variable ``s`` or the
adaptive gains). Adding a traced signal is one entry in one of these tuples.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

__all__ = ["Signal", "COMMON", "THRUSTER_DYNAMICS", "DOFS", "POSE_UNITS", "RATE_UNITS", "WRENCH_UNITS", "ACCEL_UNITS",
           "label", "trace_signals", "check_signals"]

DOFS = "x, y, z, phi, theta, psi"
POSE_UNITS = "m, m, m, rad, rad, rad"
RATE_UNITS = "m/s, m/s, m/s, rad/s, rad/s, rad/s"
ACCEL_UNITS = "m/s^2, m/s^2, m/s^2, rad/s^2, rad/s^2, rad/s^2"
WRENCH_UNITS = "N, N, N, N m, N m, N m"


@dataclass(frozen=True)
class Signal:
    """One traced per-sample quantity.

    ``width``: number of columns, or ``"thrusters"`` / ``"joints"``: the system's number of thrusters
    (per-thruster signals) or of arm joints; ``units``: one unit, or one per column, comma-separated; ``frame``: ``"{n}"`` (NED),
    ``"{b}"`` (body, at the COB) or ``""``; ``columns``: comma-separated column names (``""``: the
    signal's name); ``value(ctx)``: the CasADi expression of the signal in the compiled step.
    """

    name: str
    width: int | str
    units: str
    frame: str
    columns: str
    description: str
    value: Callable[[Any], Any]

    def n(self, n_thrusters: int = 6, n_joints: int = 6) -> int:
        if self.width == "thrusters":
            return n_thrusters
        if self.width == "joints":
            return n_joints
        return self.width

    def column_names(self, n: int | None = None) -> list[str]:
        """Column names; ``n``: the number of columns of a system-sized signal (default 6)."""
        if self.columns:
            return [c.strip() for c in self.columns.split(",")]
        k = self.n(n or 6, n or 6) if isinstance(self.width, str) else self.width
        if k == 1:
            return [self.name]
        return [f"{self.name}{i + 1}" for i in range(k)]


COMMON: tuple[Signal, ...] = (
    Signal("t", 1, "s", "", "t", "time of controller sample k, t_k = k h", lambda c: c.t),
    Signal("eta", 6, POSE_UNITS, "{n}", DOFS, "true pose eta = [x y z phi theta psi] (ZYX Euler angles)",
           lambda c: c.eta),
    Signal("nu", 6, RATE_UNITS, "{b}", "u, v, w, p, q, r", "true body velocity nu = [u v w p q r] about the COB",
           lambda c: c.nu),
    Signal("eta_hat", 6, POSE_UNITS, "{n}", DOFS, "EKF estimate of eta (the controller's input)",
           lambda c: c.eta_hat),
    Signal("eta_ref", 6, POSE_UNITS, "{n}", DOFS,
           "reference y1 of the adaptive tracking differentiator (eq. 12-13) tracked by the controller; RMSE's reference",
           lambda c: c.eta_ref),
    Signal("tau_cmd", 6, WRENCH_UNITS, "{b}", "X, Y, Z, K, M, N",
           "commanded body wrench tau_v (eq. 20: J(eta_hat)^T tau_eta), before allocation and saturation; CHAT's input",
           lambda c: c.tau_v),
    Signal("thrust", "thrusters", "N", "", "",
           "thrust per thruster after saturation to [u_min, u_max], held over the sample (Appendix B); with "
           "thruster dynamics the thrust each delivers at t_k", lambda c: c.u_sat),
    Signal("f_true", 6, WRENCH_UNITS, "{n}", DOFS,
           "true total disturbance of eq. 6: Mhat eta_ddot - J^-T tau_v,realised", lambda c: c.f_true),
    Signal("q", "joints", "rad", "", "", "manipulator joint angles (prescribed trajectory)",
           lambda c: c.q),
    Signal("payload", 1, "1", "", "payload", "payload fraction in [0, 1] (ramped over the scenario's payload_ramp)",
           lambda c: c.payload),
)


# the signals of a system whose thrusters have dynamics (docs/model.md §9), after COMMON
THRUSTER_DYNAMICS: tuple[Signal, ...] = (
    Signal("thrust_cmd", "thrusters", "N", "", "",
           "thrust the allocation asks of each thruster at t_k, saturated to [u_min, u_max] (the lag's target)",
           lambda c: c.u_cmd),
    Signal("command", "thrusters", "map unit", "", "",
           "command sent to each thruster at t_k, in its map's unit (PWM us, normalised, rad/s): the inverse map "
           "of thrust_cmd", lambda c: c.command),
    Signal("tau_delivered", 6, WRENCH_UNITS, "{b}", "X, Y, Z, K, M, N",
           "body wrench the thrusters deliver at t_k (B times thrust); CHAT on it is chat_delivered",
           lambda c: c.tau_del),
)


def trace_signals(controller, structure=None) -> tuple[Signal, ...]:
    """The traced signals of a run of ``controller`` (an :class:`arvcas.controllers.Controller`) on a system
    of ``structure`` (:class:`arvcas.system.systemfile.Structure`; None: instantaneous thrusters), in order."""
    dyn = THRUSTER_DYNAMICS if structure is not None and structure.has_thruster_dynamics else ()
    return COMMON + dyn + tuple(controller.signals)


def check_signals(signals) -> None:
    """Names must be unique identifiers, not clash with a Result attribute; raises ValueError."""
    seen = set()
    reserved = {"controller", "gains", "seed", "chat", "rmse", "ok", "t_fail", "series", "meta", "h", "e",
                "diverged", "config_text", "params_vector", "uncertainty", "phase", "version", "signals"}
    for s in signals:
        if not s.name.isidentifier() or s.name in seen or s.name in reserved:
            raise ValueError(f"signal {s.name!r}: names must be unique identifiers and not one of {sorted(reserved)}")
        seen.add(s.name)


def label(sig: Signal, column: int | None = None) -> str:
    """An axis label: ``name [unit]`` (the column's own unit where units differ per column)."""
    units = [u.strip() for u in sig.units.split(",")]
    u = units[column] if column is not None and len(units) > 1 and column < len(units) else units[0]
    name = sig.column_names()[column] if column is not None and sig.width != 1 else sig.name
    return f"{name} [{u}]" if u and u != "1" else name
