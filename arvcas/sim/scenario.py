"""The station-keeping experiment of section 4 (SPEC 4): configuration, arm trajectory, payload,
disturbance (eq. 41) and sensor noise.

The configuration is data (``data/scenario.toml``), loaded strictly into a frozen
:class:`ScenarioConfig`. Trajectory, payload and disturbance are pure functions of time that work on
CasADi types, so the compiled closed loop evaluates them inside its time loop.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from arvcas import tomlfile

__all__ = [
    "ScenarioConfig", "ScenarioError", "load_scenario", "loads_scenario", "default_scenario_path",
    "quintic", "joint_trajectory", "payload_profile", "disturbance", "disturbance_tabulated", "noise_sequence",
    "check_joint_limits", "n_samples",
]


class ScenarioError(ValueError):
    """One-line error naming the scenario file (or argument) and key."""


# section.key -> (length or 0 for scalar, sign rule)
_SCHEMA: dict[str, tuple[int, str]] = {
    "time.duration": (0, "pos"),
    "time.h_plant": (0, "pos"),
    "time.h": (0, "pos"),
    "initial.eta0": (6, "any"),
    "initial.nu0": (6, "any"),
    "initial.eta_d": (6, "any"),
    "arm.qg": (6, "any"),
    "arm.hold_until": (0, "nonneg"),
    "arm.reach_end": (0, "pos"),
    "arm.payload_on": (0, "nonneg"),
    "arm.payload_ramp": (0, "pos"),
    "arm.return_start": (0, "nonneg"),
    "arm.return_end": (0, "pos"),
    "disturbance.offset": (6, "any"),
    "disturbance.amplitude": (6, "any"),
    "disturbance.freq": (6, "nonneg"),
    "disturbance.phase": (6, "any"),
    "sensors.var_position": (0, "nonneg"),
    "sensors.var_attitude": (0, "nonneg"),
    "sensors.var_velocity": (0, "nonneg"),
    "ekf.q_eta": (0, "pos"),
    "ekf.q_nu": (0, "pos"),
    "uncertainty.C_factor": (0, "nonneg"),
    "uncertainty.D_factor": (0, "nonneg"),
    "uncertainty.g_factor": (0, "nonneg"),
    "uncertainty.arm_factor": (0, "nonneg"),
    "atd.T": (0, "pos"),
    "atd.A_min": (0, "pos"),
    "limits.e_position": (0, "pos"),
    "limits.e_attitude": (0, "pos"),
}


def _field(name: str) -> str:
    return name.replace(".", "_")


@dataclass(frozen=True)
class ScenarioConfig:
    """SI values of ``scenario.toml`` (angles in rad). Field ``a_b`` is key ``a.b`` of the file."""

    time_duration: float
    time_h_plant: float
    time_h: float
    initial_eta0: tuple
    initial_nu0: tuple
    initial_eta_d: tuple
    arm_qg: tuple
    arm_hold_until: float
    arm_reach_end: float
    arm_payload_on: float
    arm_payload_ramp: float
    arm_return_start: float
    arm_return_end: float
    disturbance_offset: tuple
    disturbance_amplitude: tuple
    disturbance_freq: tuple
    disturbance_phase: tuple
    sensors_var_position: float
    sensors_var_attitude: float
    sensors_var_velocity: float
    ekf_q_eta: float
    ekf_q_nu: float
    uncertainty_C_factor: float
    uncertainty_D_factor: float
    uncertainty_g_factor: float
    uncertainty_arm_factor: float
    atd_T: float
    atd_A_min: float
    limits_e_position: float
    limits_e_attitude: float
    text: str = ""  # the file's text, stored in result files
    path: str = ""

    # derived ------------------------------------------------------------------------------
    @property
    def substeps(self) -> int:
        """Plant RK4 steps per controller sample (h / h_plant, an integer)."""
        return int(round(self.time_h / self.time_h_plant))

    @property
    def uncertainty(self) -> np.ndarray:
        """[C, D, g, arm] factors of the nominal model (SPEC 4)."""
        return np.array([self.uncertainty_C_factor, self.uncertainty_D_factor,
                         self.uncertainty_g_factor, self.uncertainty_arm_factor])

    @property
    def sensor_variances(self) -> np.ndarray:
        """12 variances of [eta; nu] measurement noise (section 4.1)."""
        return np.array([self.sensors_var_position] * 3 + [self.sensors_var_attitude] * 3
                        + [self.sensors_var_velocity] * 6)

    def to_toml(self) -> str:
        """The effective configuration as scenario TOML (SI values): ``loads_scenario`` gives it back.

        Stored in result files, so a run made with a modified config (``dataclasses.replace``,
        :meth:`with_h`) records what it really used, not the text of the file it started from.
        """
        lines = ["# arvcas scenario, effective values in SI units (angles in rad)"]
        section = None
        for name, (n, _rule) in _SCHEMA.items():
            sec, key = name.split(".")
            if sec != section:
                lines.append(f"\n[{sec}]")
                section = sec
            v = getattr(self, _field(name))
            val = "[" + ", ".join(repr(float(x)) for x in v) + "]" if n else repr(float(v))
            lines.append(f'{key} = {{ value = {val}, unit = "SI", source = "effective value" }}')
        return "\n".join(lines) + "\n"

    @property
    def ekf_vector(self) -> np.ndarray:
        """[q_eta, q_nu, var_position, var_attitude, var_velocity]: the run's ``ekf`` input."""
        return np.array([self.ekf_q_eta, self.ekf_q_nu, self.sensors_var_position,
                         self.sensors_var_attitude, self.sensors_var_velocity])

    def graph_key(self) -> "ScenarioConfig":
        """The fields that shape the compiled graph (values that are run inputs zeroed)."""
        return replace(self, text="", path="", ekf_q_eta=0.0, ekf_q_nu=0.0, sensors_var_position=0.0,
                       sensors_var_attitude=0.0, sensors_var_velocity=0.0, disturbance_phase=(0.0,) * 6,
                       uncertainty_C_factor=0.0, uncertainty_D_factor=0.0, uncertainty_g_factor=0.0,
                       uncertainty_arm_factor=0.0)

    def with_h(self, h: float) -> "ScenarioConfig":
        """The same scenario at another controller sampling period (plant unchanged)."""
        cfg = replace(self, time_h=float(h))
        _check_consistency(cfg, "ScenarioConfig.with_h")
        return cfg


def default_scenario_path() -> Path:
    return Path(str(resources.files("arvcas") / "data" / "scenario.toml"))


def _unit_factors(unit: str, n: int, where: str) -> np.ndarray:
    """Per-element SI factors of a unit string: one unit for all, two for the halves of a 6-vector,
    or one per element; "deg" converts to rad."""
    parts = [u.strip() for u in unit.split(",")]
    if len(parts) == 1:
        parts = parts * n
    elif len(parts) == 2 and n == 6:
        parts = [parts[0]] * 3 + [parts[1]] * 3
    elif len(parts) != n:
        raise ScenarioError(f"{where}: unit list '{unit}' does not match {n} values")
    return np.array([math.pi / 180.0 if u == "deg" else 1.0 for u in parts])


def load_scenario(path: str | Path | None = None) -> ScenarioConfig:
    """Load and validate the scenario file; one-line :class:`ScenarioError` naming file and key."""
    p = Path(path) if path is not None else default_scenario_path()
    return loads_scenario(tomlfile.read_text(p, ScenarioError), str(p))


def loads_scenario(text: str, where: str = "<scenario text>") -> ScenarioConfig:
    """Validate scenario TOML text (e.g. stored in a result file); ``where`` names it in errors."""
    doc = tomlfile.parse(text, where, ScenarioError)
    flat: dict[str, Any] = {}
    for sec, table in doc.items():
        if not isinstance(table, dict):
            raise ScenarioError(f"{where}: '{sec}' must be a table")
        for k, v in table.items():
            flat[f"{sec}.{k}"] = v
    for name in flat:
        if name not in _SCHEMA:
            close = difflib.get_close_matches(name, list(_SCHEMA), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise ScenarioError(f"{where}: unknown key '{name}'{hint}")
    values: dict[str, Any] = {}
    for name, (n, rule) in _SCHEMA.items():
        if name not in flat:
            raise ScenarioError(f"{where}: missing key '{name}'")
        entry = flat[name]
        if not isinstance(entry, dict) or set(entry) != {"value", "unit", "source"}:
            raise ScenarioError(f"{where}: {name}: expected a table {{ value, unit, source }}")
        v = entry["value"]
        if n:
            if not isinstance(v, list) or len(v) != n:
                raise ScenarioError(f"{where}: {name}: expected a list of {n} numbers")
            arr = [_number(x, f"{where}: {name}", rule) for x in v]
        else:
            arr = [_number(v, f"{where}: {name}", rule)]
        fac = _unit_factors(str(entry["unit"]), max(n, 1), f"{where}: {name}")
        arr = np.array(arr) * fac
        values[_field(name)] = tuple(float(a) for a in arr) if n else float(arr[0])
    cfg = ScenarioConfig(**values, text=text, path=where)
    _check_consistency(cfg, where)
    return cfg


def _number(x: Any, where: str, rule: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise ScenarioError(f"{where}: value must be a number, got {type(x).__name__}")
    x = float(x)
    if not math.isfinite(x):
        raise ScenarioError(f"{where}: value must be finite, got {x}")
    if rule == "pos" and x <= 0:
        raise ScenarioError(f"{where}: value must be > 0, got {x}")
    if rule == "nonneg" and x < 0:
        raise ScenarioError(f"{where}: value must be >= 0, got {x}")
    return x


def _check_consistency(cfg: ScenarioConfig, where: str) -> None:
    r = cfg.time_h / cfg.time_h_plant
    if abs(r - round(r)) > 1e-9 or round(r) < 1:
        raise ScenarioError(f"{where}: time.h ({cfg.time_h}) must be a whole multiple of time.h_plant ({cfg.time_h_plant})")
    if not (cfg.arm_hold_until < cfg.arm_reach_end <= cfg.arm_return_start < cfg.arm_return_end):
        raise ScenarioError(f"{where}: arm times must satisfy hold_until < reach_end <= return_start < return_end")
    if cfg.time_duration < cfg.time_h:
        raise ScenarioError(f"{where}: time.duration must be at least one sample time.h")


def n_samples(cfg: ScenarioConfig) -> int:
    """Controller samples k = 0..N with t_k = k h, N = duration / h: returns N + 1."""
    return int(round(cfg.time_duration / cfg.time_h)) + 1


# ---------------------------------------------------------------------------------------------
def quintic(t, t0: float, t1: float):
    """Rest-to-rest quintic blend s(t) in [0, 1] with zero end velocity and acceleration.

    Returns (s, s_dot, s_ddot); constant outside [t0, t1].
    """
    T = t1 - t0
    tau = ca.fmin(ca.fmax((t - t0) / T, 0), 1)
    inside = ca.logic_and(t > t0, t < t1)
    s = tau**3 * (10 - 15 * tau + 6 * tau**2)
    sd = ca.if_else(inside, 30 * tau**2 * (1 - tau) ** 2 / T, 0)
    sdd = ca.if_else(inside, 60 * tau * (1 - tau) * (1 - 2 * tau) / T**2, 0)
    return s, sd, sdd


def joint_trajectory(cfg: ScenarioConfig, q0, t):
    """q, qd, qdd of SPEC 4: hold q0, quintic to qg, hold, quintic back to q0, hold."""
    qg = ca.DM(cfg.arm_qg)
    s1, sd1, sdd1 = quintic(t, cfg.arm_hold_until, cfg.arm_reach_end)
    s2, sd2, sdd2 = quintic(t, cfg.arm_return_start, cfg.arm_return_end)
    dq = qg - q0
    q = q0 + dq * (s1 - s2)
    qd = dq * (sd1 - sd2)
    qdd = dq * (sdd1 - sdd2)
    return q, qd, qdd


def payload_profile(cfg: ScenarioConfig, t):
    """Payload fraction in [0, 1]: linear ramp over [payload_on, payload_on + payload_ramp] (section 4.2)."""
    return ca.fmin(ca.fmax((t - cfg.arm_payload_on) / cfg.arm_payload_ramp, 0), 1)


def disturbance(cfg: ScenarioConfig, t, phase):
    """tau_u(t) of eq. 41 in {b}: offset + amplitude sin(freq t + phase); ``phase`` is a 6-vector input."""
    off, amp, w = ca.DM(cfg.disturbance_offset), ca.DM(cfg.disturbance_amplitude), ca.DM(cfg.disturbance_freq)
    return off + amp * ca.sin(w * t + phase)


def disturbance_tabulated(cfg: ScenarioConfig, dist_sin, dist_cos, phase_cs):
    """eq. 41 from tabulated ``sin(freq t)``, ``cos(freq t)`` and ``phase_cs = [cos(phase); sin(phase)]``.

    ``sin(w t + phase) = sin(w t) cos(phase) + cos(w t) sin(phase)``: the run tabulates the time part
    once (:mod:`arvcas.sim.schedule`) and the phase part once per run.
    """
    off, amp = ca.DM(cfg.disturbance_offset), ca.DM(cfg.disturbance_amplitude)
    return off + amp * (dist_sin * phase_cs[0:6] + dist_cos * phase_cs[6:12])


def noise_sequence(cfg: ScenarioConfig, seed: int, n: int | None = None) -> np.ndarray:
    """Sensor noise for samples k = 0..N, shape (12, N+1): seeded ``numpy.random.default_rng(seed)``."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ScenarioError(f"seed: must be a non-negative integer, got {seed!r}")
    n = n_samples(cfg) if n is None else n
    rng = np.random.default_rng(int(seed))
    std = np.sqrt(cfg.sensor_variances)
    return (rng.standard_normal((n, 12)) * std).T.copy()


def check_joint_limits(cfg: ScenarioConfig, params) -> None:
    """The trajectory's poses q0 and qg must lie within Table 1's limits (quintics stay between them)."""
    for label, q in (("arm.stow (q0)", [params[f"arm.stow.q{i}"] for i in range(1, 7)]), ("arm.qg", cfg.arm_qg)):
        for i, qi in enumerate(q, start=1):
            lo, hi = params[f"arm.joint{i}.qmin"], params[f"arm.joint{i}.qmax"]
            if not (lo - 1e-12 <= qi <= hi + 1e-12):
                raise ScenarioError(
                    f"{label}: joint {i} target {math.degrees(qi):.2f} deg outside Table 1 limits "
                    f"[{math.degrees(lo):.0f}, {math.degrees(hi):.0f}] deg"
                )

