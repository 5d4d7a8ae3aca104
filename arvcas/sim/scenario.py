"""The station-keeping experiment of section 4 (docs/model.md §4): configuration, arm trajectory, payload,
disturbance (eq. 41) and sensor noise.

The configuration is data (``data/scenario.toml``), loaded strictly into a frozen
:class:`ScenarioConfig`. Trajectory, payload and disturbance are pure functions of time that work on
CasADi types, so the compiled closed loop evaluates them inside its time loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import casadi as ca
import numpy as np

from arvcas import config, tomlfile
from arvcas.config import ge, gt, le, quantity

__all__ = [
    "ScenarioConfig", "ScenarioError", "load_scenario", "loads_scenario", "default_scenario_path",
    "quintic", "joint_trajectory", "payload_profile", "disturbance", "disturbance_tabulated", "noise_sequence",
    "check_joint_limits", "n_samples", "table_bytes", "ScenarioFile", "MAX_SUBSTEPS",
]


class ScenarioError(ValueError):
    """One-line error naming the scenario file (or argument) and key."""


# ---- the file's schema: dimension and rule beside each key (values in SI after loading) --------------
_POSE = ("length",) * 3 + ("angle",) * 3  # x, y, z, phi, theta, psi
_RATE = ("velocity",) * 3 + ("angular_velocity",) * 3  # u, v, w, p, q, r
_WRENCH = ("force",) * 3 + ("torque",) * 3  # X, Y, Z, K, M, N
MAX_SUBSTEPS = 1000  # h / h_plant: the plant's RK4 steps of one sample are unrolled in the compiled graph


@dataclass(frozen=True)
class _Time:
    duration: float = quantity("time", gt(0), le(1e6))
    h_plant: float = quantity("time", gt(0), ge(1e-6))
    h: float = quantity("time", gt(0), ge(1e-6))


@dataclass(frozen=True)
class _Initial:
    eta0: tuple[float, ...] = quantity(_POSE)
    nu0: tuple[float, ...] = quantity(_RATE)
    eta_d: tuple[float, ...] = quantity(_POSE)


@dataclass(frozen=True)
class _Arm:
    qg: tuple[float, ...] = quantity("angle", n=6)
    hold_until: float = quantity("time", ge(0))
    reach_end: float = quantity("time", gt(0))
    payload_on: float = quantity("time", ge(0))
    payload_ramp: float = quantity("time", gt(0))
    return_start: float = quantity("time", ge(0))
    return_end: float = quantity("time", gt(0))


@dataclass(frozen=True)
class _Disturbance:
    offset: tuple[float, ...] = quantity(_WRENCH)
    amplitude: tuple[float, ...] = quantity(_WRENCH)
    freq: tuple[float, ...] = quantity("angular_velocity", ge(0), n=6)
    phase: tuple[float, ...] = quantity("angle", n=6)


@dataclass(frozen=True)
class _Sensors:
    var_position: float = quantity("length^2", ge(0))
    var_attitude: float = quantity("angle^2", ge(0))
    var_velocity: float = quantity("velocity^2 or angular_velocity^2", ge(0))


@dataclass(frozen=True)
class _Ekf:
    q_eta: float = quantity("length^2 or angle^2", gt(0), per="step")  # random-walk variance per step h
    q_nu: float = quantity("velocity^2 or angular_velocity^2", gt(0), per="step")


@dataclass(frozen=True)
class _Uncertainty:
    C_factor: float = quantity("1", ge(0))
    D_factor: float = quantity("1", ge(0))
    g_factor: float = quantity("1", ge(0))
    arm_factor: float = quantity("1", ge(0))


@dataclass(frozen=True)
class _Atd:
    T: float = quantity("time", gt(0))
    A_min: float = quantity("length or angle", gt(0))


@dataclass(frozen=True)
class _Limits:
    e_position: float = quantity("length", gt(0))
    e_attitude: float = quantity("angle", gt(0))


@dataclass(frozen=True)
class ScenarioFile:
    """The scenario file's schema; key ``a.b`` of the file is field ``a_b`` of :class:`ScenarioConfig`."""

    time: _Time = config.setting()
    initial: _Initial = config.setting()
    arm: _Arm = config.setting()
    disturbance: _Disturbance = config.setting()
    sensors: _Sensors = config.setting()
    ekf: _Ekf = config.setting()
    uncertainty: _Uncertainty = config.setting()
    atd: _Atd = config.setting()
    limits: _Limits = config.setting()


_LEAVES = config.leaves(ScenarioFile)


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
        """[C, D, g, arm] factors of the nominal model (docs/model.md §4)."""
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
        for leaf in _LEAVES:
            sec, key = leaf.key.split(".")
            if sec != section:
                lines.append(f"\n[{sec}]")
                section = sec
            v = getattr(self, _field(leaf.key))
            val = "[" + ", ".join(repr(float(x)) for x in v) + "]" if leaf.n else repr(float(v))
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
        """The same scenario at another controller sampling period.

        The plant's RK4 step stays the scenario's where it divides ``h``; where it does not (h = 0.02 s
        with the default 0.05 s) it is the largest step below it that does, ``h / ceil(h / h_plant)``:
        never coarser than the scenario's, so never less accurate (results/step)."""
        h = config.check_value(ScenarioFile, "time.h", h, "ScenarioConfig.with_h", ScenarioError)
        hp, r = self.time_h_plant, h / self.time_h_plant
        if abs(r - round(r)) > 1e-9 or round(r) < 1:
            hp = h / math.ceil(r)
        cfg = replace(self, time_h=h, time_h_plant=hp)
        _check_consistency(cfg, "ScenarioConfig.with_h")
        return cfg


def default_scenario_path() -> Path:
    return Path(str(resources.files("arvcas") / "data" / "scenario.toml"))


def load_scenario(path: str | Path | None = None) -> ScenarioConfig:
    """Load and validate the scenario file; one-line :class:`ScenarioError` naming file and key."""
    p = Path(path) if path is not None else default_scenario_path()
    return loads_scenario(tomlfile.read_text(p, ScenarioError), str(p))


def loads_scenario(text: str, where: str = "<scenario text>") -> ScenarioConfig:
    """Validate scenario TOML text (e.g. stored in a result file); ``where`` names it in errors."""
    loaded = config.load_text(ScenarioFile, text, where, ScenarioError, entries=True)
    values = {_field(k): v for k, v in config.flatten(loaded.value)}
    cfg = ScenarioConfig(**values, text=text, path=where)
    _check_consistency(cfg, where)
    return cfg


def table_bytes(cfg: ScenarioConfig) -> int:
    """Bytes of the run's time table (:func:`arvcas.sim.schedule.table`): a record of
    ``schedule.RECORD_SIZE`` doubles at each of the ``2 h / h_plant + 1`` stage times of every sample,
    about 8.6 MB for the 100 s paper run at h_plant = 0.05 s (36 MB at 0.01 s). Building it holds about twice that."""
    from arvcas.sim import schedule  # schedule imports this module

    return n_samples(cfg) * schedule.n_stages(cfg) * schedule.RECORD_SIZE * 8


def _check_consistency(cfg: ScenarioConfig, where: str) -> None:
    r = cfg.time_h / cfg.time_h_plant
    if abs(r - round(r)) > 1e-9 or round(r) < 1:
        raise ScenarioError(f"{where}: time.h ({cfg.time_h}) must be a whole multiple of time.h_plant ({cfg.time_h_plant})")
    if round(r) > MAX_SUBSTEPS:
        raise ScenarioError(f"{where}: time.h: h / h_plant = {round(r)} plant steps per sample, at most "
                            f"{MAX_SUBSTEPS} (they are unrolled in the compiled sample step)")
    if not (cfg.arm_hold_until < cfg.arm_reach_end <= cfg.arm_return_start < cfg.arm_return_end):
        raise ScenarioError(f"{where}: arm times must satisfy hold_until < reach_end <= return_start < return_end")
    if cfg.time_duration < cfg.time_h:
        raise ScenarioError(f"{where}: time.duration must be at least one sample time.h")
    config.check_memory(table_bytes(cfg), f"the run's time table ({n_samples(cfg)} samples of "
                        f"{cfg.substeps} plant steps)", where, "time.duration", ScenarioError)


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
    """q, qd, qdd of docs/model.md §4: hold q0, quintic to qg, hold, quintic back to q0, hold."""
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
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise ScenarioError(f"seed: must be an integer with 0 <= seed < 2**63 (result files store it as int64), "
                            f"got {seed!r}")
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

