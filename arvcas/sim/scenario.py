"""The experiment's file (docs/model.md §4): the scenario file's schema, its strict loading into a frozen
:class:`ScenarioConfig`, its checks (alone, and against a system: joint limits, a trajectory's thrust), the
sensor sets and the sample count.

The configuration is data (``data/scenario.toml``, or a scenario file of the user's); the signals the run
evaluates from it (the arm's trajectory and payload, the disturbance of eq. 41, the current and tether, the
sensor noise) are :mod:`arvcas.sim.profiles`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np

from arvcas.sim import trajectory as trajectory_mod
from arvcas.system import config, tomlfile
from arvcas.system.config import ge, gt, le, quantity

__all__ = [
    "ScenarioConfig", "ScenarioError", "load_scenario", "loads_scenario", "default_scenario_path",
    "n_samples", "ScenarioFile", "MAX_SUBSTEPS",
    "SENSORS", "sensor_set", "measured", "held_dofs", "latencies", "MAX_LATENCY",
]


class ScenarioError(ValueError):
    """One-line error naming the scenario file (or argument) and key."""


# ---- the file's schema: dimension and rule beside each key (values in SI after loading) --------------
_POSE = ("length",) * 3 + ("angle",) * 3  # x, y, z, phi, theta, psi
_RATE = ("velocity",) * 3 + ("angular_velocity",) * 3  # u, v, w, p, q, r
_WRENCH = ("force",) * 3 + ("torque",) * 3  # X, Y, Z, K, M, N
MAX_LATENCY = 10  # controller samples a sensor's reading may lag (docs/sensors.md): its shift register is in the loop state
MAX_SUBSTEPS = 1000  # h / h_plant: the plant's RK4 steps of one sample are unrolled in the compiled graph
MAX_CURRENT_POINTS = 10_000
MAX_THRUST_NODES = 16  # time.thrust_quadrature: Gauss-Legendre nodes per half plant step


@dataclass(frozen=True)
class _Time:
    duration: float = quantity("time", gt(0), le(1e6))
    h_plant: float = quantity("time", gt(0), ge(1e-6))
    h: float = quantity("time", gt(0), ge(1e-6))
    # the thrusters' forcing within a plant step by Gauss-Legendre quadrature (docs/model.md §9): nodes per
    # half step; absent: RK4 samples the thrust at its stage times (systems with thruster dynamics only)
    thrust_quadrature: int | None = config.setting(ge(1), le(MAX_THRUST_NODES), default=None)


@dataclass(frozen=True)
class _Initial:
    eta0: tuple[float, ...] = quantity(_POSE)
    nu0: tuple[float, ...] = quantity(_RATE)
    eta_d: tuple[float, ...] = quantity(_POSE)


@dataclass(frozen=True)
class _Waypoint:
    """A joint waypoint: the arm reaches ``q`` (or its stow pose) at ``t`` by a rest-to-rest quintic."""

    t: float = quantity("time", ge(0))
    q: tuple[float, ...] = quantity("angle", n=config.ANY_LENGTH)  # () for q = "stow" in the file

    @property
    def stow(self) -> bool:
        return len(self.q) == 0


@dataclass(frozen=True)
class _Event:
    """A payload event: the payload fraction ramps linearly to ``to`` over ``[t, t + ramp]``."""

    t: float = quantity("time", ge(0))
    ramp: float = quantity("time", gt(0))
    to: float = quantity("1", ge(0), le(1))


@dataclass(frozen=True)
class _Arm:
    """The arm's motion: the paper's reach-and-return (docs/model.md §4) or a list of waypoints."""

    qg: tuple[float, ...] | None = quantity("angle", n=6, default=None)
    hold_until: float | None = quantity("time", ge(0), default=None)
    reach_end: float | None = quantity("time", gt(0), default=None)
    payload_on: float | None = quantity("time", ge(0), default=None)
    payload_ramp: float | None = quantity("time", gt(0), default=None)
    return_start: float | None = quantity("time", ge(0), default=None)
    return_end: float | None = quantity("time", gt(0), default=None)
    waypoint: tuple[_Waypoint, ...] | None = config.setting(config.Count(2, 1000), default=None)


@dataclass(frozen=True)
class _Payload:
    event: tuple[_Event, ...] = config.setting(config.Count(1, 1000))


@dataclass(frozen=True)
class _Disturbance:
    offset: tuple[float, ...] = quantity(_WRENCH)
    amplitude: tuple[float, ...] = quantity(_WRENCH)
    freq: tuple[float, ...] = quantity("angular_velocity", ge(0), n=6)
    phase: tuple[float, ...] = quantity("angle", n=6)


@dataclass(frozen=True)
class _Sensors:
    """Sensor noise variances: one per group (position, attitude, body velocity), or one per axis
    (``var_eta`` for x y z phi theta psi, ``var_nu`` for u v w p q r)."""

    var_position: float | None = quantity("length^2", ge(0), default=None)
    var_attitude: float | None = quantity("angle^2", ge(0), default=None)
    var_velocity: float | None = quantity("velocity^2 or angular_velocity^2", ge(0), default=None)
    var_eta: tuple[float, ...] | None = quantity(("length^2",) * 3 + ("angle^2",) * 3, ge(0), default=None)
    var_nu: tuple[float, ...] | None = quantity(("velocity^2",) * 3 + ("angular_velocity^2",) * 3, ge(0),
                                                default=None)
    # the vehicle's sensor set (docs/sensors.md): a sensor is fitted when its sampling period is given; none
    # given: the whole [eta; nu] is measured at every sample (section 4.1)
    imu_period: float | None = quantity("time", gt(0), default=None)
    depth_period: float | None = quantity("time", gt(0), default=None)
    dvl_period: float | None = quantity("time", gt(0), default=None)
    position_period: float | None = quantity("time", gt(0), default=None)
    # each fitted sensor's latency: a reading that arrives at sample k is the state of sample k - d (a whole
    # number d of controller samples, at most MAX_LATENCY); none given: 0, a reading is the state of its sample
    imu_latency: float | None = quantity("time", ge(0), default=None)
    depth_latency: float | None = quantity("time", ge(0), default=None)
    dvl_latency: float | None = quantity("time", ge(0), default=None)
    position_latency: float | None = quantity("time", ge(0), default=None)

    def _config_check(self, given: frozenset[str]) -> None:
        group = [k for k in ("var_position", "var_attitude", "var_velocity") if k in given]
        axis = [k for k in ("var_eta", "var_nu") if k in given]
        if group and axis:
            raise config.Invalid(axis[0], "give the group variances (var_position, var_attitude, var_velocity) "
                                          "or the per-axis ones (var_eta, var_nu), not both")
        if axis and len(axis) != 2:
            raise config.Invalid("var_nu" if "var_eta" in axis else "var_eta",
                                 "missing: per-axis variances need var_eta and var_nu")
        if not axis and len(group) != 3:
            missing = next(k for k in ("var_position", "var_attitude", "var_velocity") if k not in group)
            raise config.Invalid(missing, "missing (or give per-axis var_eta and var_nu)")


@dataclass(frozen=True)
class _CurrentPoint:
    """One point of a current table: the current's velocity in {n} at time ``t`` and depth ``depth``."""

    t: float = quantity("time", ge(0))
    depth: float = quantity("length")
    velocity: tuple[float, ...] = quantity("velocity", n=3)


@dataclass(frozen=True)
class _Current:
    """The water's velocity in {n} (north, east, down), irrotational: constant, or a table in time and depth
    (every depth at every time; linear in between, held beyond the ends)."""

    velocity: tuple[float, ...] | None = quantity("velocity", n=3, default=None)
    point: tuple[_CurrentPoint, ...] | None = config.setting(config.Count(1, MAX_CURRENT_POINTS), default=None)

    def _config_check(self, given: frozenset[str]) -> None:
        if ("velocity" in given) == ("point" in given):
            raise config.Invalid("velocity", "give a constant velocity or a table of [[current.point]], one of them")


@dataclass(frozen=True)
class _Tether:
    """A quasi-static tether from the surface to ``attachment`` (body frame): half the drag of its ``length``
    in the current, normal to a vertical cable, plus a steady ``pull`` in {n} (docs/model.md §10)."""

    attachment: tuple[float, ...] = quantity("length", n=3)
    length: float = quantity("length", ge(0))
    diameter: float = quantity("length", ge(0))
    Cn: float = quantity("1", ge(0))
    pull: tuple[float, ...] = quantity("force", n=3)


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
class _TrajPoint:
    """A vehicle waypoint: the pose ``eta`` at time ``t``; ``rate`` its eta_dot there (``quintic`` segments)."""

    t: float = quantity("time", ge(0))
    eta: tuple[float, ...] = quantity(_POSE)
    rate: tuple[float, ...] | None = quantity(_RATE, default=None)


# the keys of each trajectory pattern (docs/tasks.md): required, then optional
TRAJECTORY_PATTERNS = {
    "waypoints": (("waypoint",), ("segment",)),
    "lawnmower": (("legs", "leg_length", "spacing", "speed"), ("segment", "start", "heading")),
    "approach": (("target", "duration"), ("start",)),
}


@dataclass(frozen=True)
class _Trajectory:
    """The vehicle's desired trajectory (docs/tasks.md): waypoints with times, a lawnmower, or approach then
    hold, with minimum-jerk or quintic segments."""

    pattern: str = config.setting(config.Choices(tuple(TRAJECTORY_PATTERNS), "trajectory pattern"))
    segment: str = config.setting(config.Choices(("minimum_jerk", "quintic"), "segment shape"), default="minimum_jerk")
    waypoint: tuple[_TrajPoint, ...] | None = config.setting(config.Count(2, 10_000), default=None)
    start: float = quantity("time", ge(0), default=0.0)
    legs: int | None = config.setting(ge(1), le(1000), default=None)
    leg_length: float | None = quantity("length", gt(0), default=None)
    spacing: float | None = quantity("length", gt(0), default=None)
    speed: float | None = quantity("velocity", gt(0), default=None)
    heading: float | None = quantity("angle", default=None)
    target: tuple[float, ...] | None = quantity(_POSE, default=None)
    duration: float | None = quantity("time", gt(0), default=None)

    def _config_check(self, given: frozenset[str]) -> None:
        need, opt = TRAJECTORY_PATTERNS[self.pattern]
        for k in sorted(given - {"pattern"}):
            if k not in need + opt:
                raise config.Invalid(k, f"not a key of pattern '{self.pattern}' (its keys: {', '.join(need + opt)})")
        for k in need:
            if k not in given:
                raise config.Invalid(k, f"missing: pattern '{self.pattern}' needs {', '.join(need)}")
        ws = self.waypoint or ()
        for j, w in enumerate(ws, start=1):
            if j > 1 and not w.t > ws[j - 2].t:
                raise config.Invalid(f"waypoint[{j}].t", f"{w.t:g} s must be after waypoint {j - 1}'s {ws[j - 2].t:g} s "
                                                         f"(times increase strictly)")
            if w.rate is not None and self.segment != "quintic":
                raise config.Invalid(f"waypoint[{j}].rate", f"a waypoint's rate goes with segment = \"quintic\" (a "
                                                            f"{self.segment} segment is rest to rest)")
        poses = [(f"waypoint[{j}].eta", w.eta) for j, w in enumerate(ws, start=1)] + [("target", self.target or (0,) * 6)]
        for key, eta in poses:
            if not abs(eta[4]) < math.pi / 2:
                raise config.Invalid(key, f"pitch {math.degrees(eta[4]):g} deg is at or beyond +-90 deg, where the "
                                          f"Euler angles are singular")


@dataclass(frozen=True)
class ScenarioFile:
    """The scenario file's schema; key ``a.b`` of the file is field ``a_b`` of :class:`ScenarioConfig`."""

    time: _Time = config.setting()
    initial: _Initial = config.setting()
    arm: _Arm = config.setting()  # no [arm] section (or an empty one): the arm, if any, holds its stow pose
    disturbance: _Disturbance = config.setting()
    sensors: _Sensors = config.setting()
    ekf: _Ekf = config.setting()
    uncertainty: _Uncertainty = config.setting()
    atd: _Atd = config.setting()
    limits: _Limits = config.setting()
    payload: _Payload | None = config.setting(default=None)  # events, with [[arm.waypoint]]
    current: _Current | None = config.setting(default=None)  # the water's velocity (docs/model.md §10)
    tether: _Tether | None = config.setting(default=None)
    trajectory: _Trajectory | None = config.setting(default=None)  # the vehicle's task (docs/tasks.md)


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
    arm_qg: tuple | None
    arm_hold_until: float | None
    arm_reach_end: float | None
    arm_payload_on: float | None
    arm_payload_ramp: float | None
    arm_return_start: float | None
    arm_return_end: float | None
    arm_waypoint: tuple | None
    payload_event: tuple | None
    disturbance_offset: tuple
    disturbance_amplitude: tuple
    disturbance_freq: tuple
    disturbance_phase: tuple
    sensors_var_position: float | None
    sensors_var_attitude: float | None
    sensors_var_velocity: float | None
    sensors_var_eta: tuple | None
    sensors_var_nu: tuple | None
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
    current_velocity: tuple | None = None
    current_point: tuple | None = None
    tether_attachment: tuple | None = None
    tether_length: float | None = None
    tether_diameter: float | None = None
    tether_Cn: float | None = None
    tether_pull: tuple | None = None
    trajectory_pattern: str | None = None  # the vehicle's desired trajectory (docs/tasks.md); None: station keeping
    trajectory_segment: str | None = None
    trajectory_waypoint: tuple | None = None
    trajectory_start: float | None = None
    trajectory_legs: int | None = None
    trajectory_leg_length: float | None = None
    trajectory_spacing: float | None = None
    trajectory_speed: float | None = None
    trajectory_heading: float | None = None
    trajectory_target: tuple | None = None
    trajectory_duration: float | None = None
    time_thrust_quadrature: int | None = None  # nodes per half plant step for the thrusters' forcing (docs/model.md §9)
    sensors_imu_period: float | None = None  # the sensor set (docs/sensors.md); all None: [eta; nu] in full
    sensors_depth_period: float | None = None
    sensors_dvl_period: float | None = None
    sensors_position_period: float | None = None
    sensors_imu_latency: float | None = None  # each sensor's latency (docs/sensors.md); None: 0
    sensors_depth_latency: float | None = None
    sensors_dvl_latency: float | None = None
    sensors_position_latency: float | None = None
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
    def per_axis_sensors(self) -> bool:
        """The sensor variances are given per axis (``var_eta``, ``var_nu``), not per group."""
        return self.sensors_var_eta is not None

    @property
    def sensor_variances(self) -> np.ndarray:
        """12 variances of [eta; nu] measurement noise (section 4.1)."""
        if self.per_axis_sensors:
            return np.array(self.sensors_var_eta + self.sensors_var_nu, dtype=float)
        return np.array([self.sensors_var_position] * 3 + [self.sensors_var_attitude] * 3
                        + [self.sensors_var_velocity] * 6)

    # the water (docs/model.md §10): a run input, ``water`` -------------------------------------------
    @property
    def current(self) -> str:
        """``"none"``, ``"constant"`` or ``"table"``."""
        return "constant" if self.current_velocity is not None else "table" if self.current_point else "none"

    @property
    def current_grid(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The current table's distinct times and depths, increasing."""
        pts = self.current_point or ()
        return tuple(sorted({p.t for p in pts})), tuple(sorted({p.depth for p in pts}))

    @property
    def has_tether(self) -> bool:
        return self.tether_length is not None

    @property
    def has_water(self) -> bool:
        return self.current != "none" or self.has_tether

    @property
    def water_vector(self) -> np.ndarray:
        """The run's ``water`` input (:meth:`water_names`): the current (a constant velocity in {n}, or the
        table's times, depths and velocities, time-major), then the tether's numbers."""
        v: list[float] = []
        if self.current == "constant":
            v += list(self.current_velocity)
        elif self.current == "table":
            ts, zs = self.current_grid
            at = {(p.t, p.depth): p.velocity for p in self.current_point}
            v += list(ts) + list(zs)
            for t in ts:
                for z in zs:
                    v += list(at[(t, z)])
        if self.has_tether:
            v += [*self.tether_attachment, self.tether_length, self.tether_diameter, self.tether_Cn, *self.tether_pull]
        return np.array(v, dtype=float)

    def water_names(self) -> list[str]:
        """Names of the ``water`` input's entries (SI units)."""
        out: list[str] = []
        if self.current == "constant":
            out += [f"current.velocity.{c}" for c in "NED"]
        elif self.current == "table":
            ts, zs = self.current_grid
            out += [f"current.t.{i}" for i in range(len(ts))] + [f"current.depth.{j}" for j in range(len(zs))]
            out += [f"current.velocity.{i}.{j}.{c}" for i in range(len(ts)) for j in range(len(zs)) for c in "NED"]
        if self.has_tether:
            out += [f"tether.attachment.{c}" for c in "xyz"] + ["tether.length", "tether.diameter", "tether.Cn"]
            out += [f"tether.pull.{c}" for c in "NED"]
        return out

    # the vehicle's task (docs/tasks.md): the desired trajectory, sampled into the run's time table -------
    @property
    def has_trajectory(self) -> bool:
        """A desired trajectory replaces the set point ``initial.eta_d`` (docs/tasks.md)."""
        return self.trajectory_pattern is not None

    def trajectory_values(self) -> tuple:
        """The trajectory's fields (hashable): with :meth:`graph_key` they key the time table."""
        return tuple(getattr(self, f.name) for f in dataclasses.fields(self) if f.name.startswith("trajectory_"))

    def trajectory(self) -> "trajectory_mod.Trajectory":
        """The desired trajectory (:class:`arvcas.sim.trajectory.Trajectory`); the lawnmower and the approach
        start from the set point ``initial.eta_d``, the station held until the task starts."""
        pat, seg = self.trajectory_pattern, self.trajectory_segment
        if pat == "waypoints":
            ws = self.trajectory_waypoint
            rates = None
            if seg == "quintic" and any(w.rate is not None for w in ws):
                auto = trajectory_mod.default_rates([w.t for w in ws], [w.eta for w in ws])
                rates = [auto[j] if w.rate is None else w.rate for j, w in enumerate(ws)]
            return trajectory_mod.from_waypoints([w.t for w in ws], [w.eta for w in ws], seg, rates)
        if pat == "lawnmower":
            t, P = trajectory_mod.lawnmower(self.initial_eta_d, self.trajectory_start, self.trajectory_legs,
                                            self.trajectory_leg_length, self.trajectory_spacing, self.trajectory_speed,
                                            self.trajectory_heading)
            return trajectory_mod.from_waypoints(t, P, seg)
        if pat == "approach":
            t, P = trajectory_mod.approach(self.initial_eta_d, self.trajectory_target, self.trajectory_start,
                                           self.trajectory_duration)
            return trajectory_mod.from_waypoints(t, P, "minimum_jerk")
        raise ValueError(f"trajectory: no pattern {pat!r} (a graph key has no trajectory to sample)")

    def reference(self) -> np.ndarray:
        """The desired trajectory at the sample times t_k, ``(12, N + 1)``: ``eta_d`` then ``eta_d_dot`` (rows)
        (the time table's reference rows, :func:`arvcas.sim.schedule.table`)."""
        p, v, _ = self.trajectory().sample(np.arange(n_samples(self)) * self.time_h)
        return np.vstack([p.T, v.T])

    def to_toml(self) -> str:
        """The effective configuration as scenario TOML (SI values): ``loads_scenario`` gives it back.

        Stored in result files, so a run made with a modified config (``dataclasses.replace``,
        :meth:`with_h`) records what it really used, not the text of the file it started from.
        """
        lines = ["# arvcas scenario, effective values in SI units (angles in rad)"]
        section = None
        entry = lambda k, v: f'{k} = {{ value = {_num(v)}, unit = "SI", source = "effective value" }}'  # noqa: E731
        tables = lines  # array tables are the last entries of their sections (the schema's order)
        for leaf in _LEAVES:
            sec, key = leaf.key.split(".")
            v = getattr(self, _field(leaf.key))
            if v is None or (sec == "trajectory" and key not in ("pattern", *sum(TRAJECTORY_PATTERNS[self.trajectory_pattern], ()))):
                continue
            if sec != section:
                lines.append(f"\n[{sec}]")
                section = sec
            if leaf.kind == "tables":
                for item in v:
                    tables.append(f"\n[[{sec}.{key}]]")
                    for f in dataclasses.fields(item):
                        x = getattr(item, f.name)
                        if x is None:
                            continue
                        tables.append('q = "stow"' if f.name == "q" and len(x) == 0 else entry(f.name, x))
                continue
            lines.append(entry(key, v))
        return "\n".join(lines) + "\n"

    @property
    def ekf_vector(self) -> np.ndarray:
        """The run's ``ekf`` input: [q_eta, q_nu, var_position, var_attitude, var_velocity], or with
        per-axis sensors [q_eta, q_nu, the 12 variances]."""
        if self.per_axis_sensors:
            return np.array([self.ekf_q_eta, self.ekf_q_nu, *self.sensor_variances])
        return np.array([self.ekf_q_eta, self.ekf_q_nu, self.sensors_var_position,
                         self.sensors_var_attitude, self.sensors_var_velocity])

    def graph_key(self) -> "ScenarioConfig":
        """The fields that shape the compiled graph (values that are run inputs zeroed; the current table's
        points become their grid indices, so that only its shape keys the graph)."""
        z6 = (0.0,) * 6
        group = not self.per_axis_sensors
        water = {}
        if self.current == "constant":
            water["current_velocity"] = (0.0,) * 3
        elif self.current == "table":
            ts, zs = self.current_grid
            water["current_point"] = tuple(_CurrentPoint(float(ts.index(p.t)), float(zs.index(p.depth)), (0.0,) * 3)
                                           for p in sorted(self.current_point, key=lambda p: (p.t, p.depth)))
        if self.has_tether:
            water |= {"tether_attachment": (0.0,) * 3, "tether_length": 0.0, "tether_diameter": 0.0,
                      "tether_Cn": 0.0, "tether_pull": (0.0,) * 3}
        if self.has_trajectory:  # sampled into the time table: only its presence shapes the graph
            water |= {f.name: None for f in dataclasses.fields(self) if f.name.startswith("trajectory_")}
            water["trajectory_pattern"] = "table"
        # a latency of 0 is no latency: the same graph as none given (docs/sensors.md)
        water |= {f"sensors_{n}_latency": None for n in SENSORS if not getattr(self, f"sensors_{n}_latency")}
        return replace(self, text="", path="", ekf_q_eta=0.0, ekf_q_nu=0.0,
                       sensors_var_position=0.0 if group else None, sensors_var_attitude=0.0 if group else None,
                       sensors_var_velocity=0.0 if group else None, sensors_var_eta=None if group else z6,
                       sensors_var_nu=None if group else z6, disturbance_phase=z6,
                       uncertainty_C_factor=0.0, uncertainty_D_factor=0.0, uncertainty_g_factor=0.0,
                       uncertainty_arm_factor=0.0, **water)

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
    """Load and validate the scenario file; one-line :class:`ScenarioError` naming file and key.

    An event of the file that starts at or after its run's end is warned (:class:`ScenarioWarning`,
    :func:`_check_within_run`): it changes nothing, likely a slip of units or of ``time.duration``, but a
    shortened copy of a scenario (``to_toml`` of a replaced duration) has such events on purpose."""
    p = Path(path) if path is not None else default_scenario_path()
    cfg = loads_scenario(tomlfile.read_text(p, ScenarioError), str(p))
    _check_within_run(cfg, str(p))
    return cfg


def _check_within_run(cfg: ScenarioConfig, where: str) -> None:
    """No event of the file starts at or after the run's end (it would change nothing: likely a slip of
    units or of time.duration): an arm motion (its start), a payload event, the paper's reach, grasp
    and return."""
    T = cfg.time_duration
    late = [(f"arm.waypoint[{j}].t", w.t) for j, w in enumerate(cfg.arm_waypoint or (), start=1)
            if j > 1 and cfg.arm_waypoint[j - 2].t >= T]
    late += [(f"payload.event[{j}].t", e.t) for j, e in enumerate(cfg.payload_event or (), start=1) if e.t >= T]
    if cfg.arm_waypoint is None and cfg.arm_qg is not None:
        late += [(f"arm.{k}", getattr(cfg, "arm_" + k)) for k in ("hold_until", "payload_on", "return_start")
                 if getattr(cfg, "arm_" + k) >= T]
    task = None  # the vehicle's task: its start after the run's end (it runs nothing)
    if cfg.has_trajectory:
        times = cfg.trajectory().times
        key = "trajectory.waypoint[1].t" if cfg.trajectory_pattern == "waypoints" else "trajectory.start"
        if times[0] >= T:
            task = (key, float(times[0]), "the task starts at or after the run's end, so it runs nothing")
    # a waypoint whose motion starts within the run but ends after it is never reached
    unreached = [(f"arm.waypoint[{j}].t", w.t) for j, w in enumerate(cfg.arm_waypoint or (), start=1)
                 if w.t > T and (j == 1 or cfg.arm_waypoint[j - 2].t < T)]
    if cfg.has_trajectory and task is None and cfg.trajectory().times[-1] > T:
        ts = cfg.trajectory().times
        j = int(np.argmax(ts > T))
        unreached.append((f"trajectory.waypoint[{j + 1}].t" if cfg.trajectory_pattern == "waypoints" else
                          f"trajectory (point {j + 1} of {len(ts)})", float(ts[j])))
    found = []
    if late:
        key, t = late[0]
        more = f" (and {len(late) - 1} more)" if len(late) > 1 else ""
        found.append(f"{where}: {key}: {t:g} s: this event starts at or after the run's end (time.duration {T:g} s), "
                     f"so it changes nothing{more}")
    if task is not None:
        found.append(f"{where}: {task[0]}: {task[1]:g} s: {task[2]} (time.duration {T:g} s)")
    for key, t in unreached:
        found.append(f"{where}: {key}: {t:g} s is after the run's end (time.duration {T:g} s): this waypoint is "
                     f"never reached")
    for msg in found:
        if msg not in _WARNED:  # once per process
            import warnings

            _WARNED.add(msg)
            warnings.warn(msg, ScenarioWarning, stacklevel=3)


class ScenarioWarning(UserWarning):
    """A scenario file's number that is allowed but changes nothing (an event after the run's end)."""


_WARNED: set[str] = set()


def loads_scenario(text: str, where: str = "<scenario text>") -> ScenarioConfig:
    """Validate scenario TOML text (e.g. stored in a result file); ``where`` names it in errors."""
    doc = tomlfile.parse(text, where, ScenarioError)
    doc.setdefault("arm", {})  # no [arm]: no arm motion (a system without an arm needs none)
    arm = doc.get("arm")
    if isinstance(arm, dict) and isinstance(arm.get("waypoint"), list):  # q = "stow": the system's stow pose
        stow = {"value": [], "unit": "rad", "source": "q = \"stow\": the system's stow pose"}
        arm["waypoint"] = [dict(w, q=stow) if isinstance(w, dict) and w.get("q") == "stow" else w
                           for w in arm["waypoint"]]
    traj = doc.get("trajectory")
    if isinstance(traj, dict):  # pattern = "lawnmower": a name needs no unit or source
        for k in ("pattern", "segment"):
            if isinstance(traj.get(k), str):
                traj[k] = {"value": traj[k], "unit": "1", "source": "a name"}
    loaded = config.load_doc(ScenarioFile, doc, where, ScenarioError, entries=True)
    values = {_field(leaf.key): _get(loaded.value, leaf.attrs) for leaf in _LEAVES}
    cfg = _wrap_angles(ScenarioConfig(**values, text=text, path=where), where)
    _check_consistency(cfg, where)
    return cfg


def _wrap_angles(cfg: ScenarioConfig, where: str) -> ScenarioConfig:
    """The initial pose's and the set-point's roll and yaw wrapped into [-pi, pi] (720 deg is 0 deg: the
    controllers act on eta - eta_d, so an unwrapped set-point asks for whole turns); an angle already
    in range is kept as it is. A pitch at or beyond +-90 deg is refused: the ZYX Euler angles are
    singular there."""
    out = {}
    for key in ("initial_eta0", "initial_eta_d"):
        eta = list(getattr(cfg, key))
        label = key.replace("_", ".", 1)
        if not abs(eta[4]) < math.pi / 2:
            raise ScenarioError(f"{where}: {label}: pitch {math.degrees(eta[4]):g} deg is at or beyond +-90 deg, "
                                f"where the Euler angles are singular")
        for i in (3, 5):
            if abs(eta[i]) > math.pi:
                eta[i] = math.remainder(eta[i], 2 * math.pi)
        out[key] = tuple(eta)
    return replace(cfg, **out)


def _check_motion_steps(cfg: ScenarioConfig, where: str) -> None:
    """No arm motion is shorter than the plant step: a quintic between two RK4 stage times would move the
    arm with no reaction on the vehicle."""
    hp = cfg.time_h_plant
    ws = cfg.arm_waypoint or ()
    for j, w in enumerate(ws, start=1):
        if j > 1 and w.t - ws[j - 2].t < hp - 1e-12:
            raise ScenarioError(f"{where}: arm.waypoint[{j}].t: the motion from waypoint {j - 1} takes "
                                f"{w.t - ws[j - 2].t:g} s, less than the plant step time.h_plant ({hp:g} s): the "
                                f"plant would not see it")
    if cfg.arm_waypoint is None and cfg.arm_return_end is not None:
        for k0, k1 in (("hold_until", "reach_end"), ("return_start", "return_end")):
            if getattr(cfg, "arm_" + k1) - getattr(cfg, "arm_" + k0) < hp - 1e-12:
                raise ScenarioError(f"{where}: arm.{k1}: the motion from arm.{k0} is shorter than the plant step "
                                    f"time.h_plant ({hp:g} s): the plant would not see it")


def _check_consistency(cfg: ScenarioConfig, where: str) -> None:
    r = cfg.time_h / cfg.time_h_plant
    if abs(r - round(r)) > 1e-9 or round(r) < 1:
        raise ScenarioError(f"{where}: time.h ({cfg.time_h}) must be a whole multiple of time.h_plant ({cfg.time_h_plant})")
    if round(r) > MAX_SUBSTEPS:
        raise ScenarioError(f"{where}: time.h: h / h_plant = {round(r)} plant steps per sample, at most "
                            f"{MAX_SUBSTEPS} (they are unrolled in the compiled sample step)")
    _check_motion(cfg, where)
    _check_motion_steps(cfg, where)
    _check_sensors(cfg, where)
    _check_current(cfg, where)
    if cfg.time_duration < cfg.time_h:
        raise ScenarioError(f"{where}: time.duration must be at least one sample time.h")


# ---- the sensor set (docs/sensors.md) ----------------------------------------------------------------
# each sensor: the components of [eta; nu] (x y z phi theta psi u v w p q r) it measures
SENSORS = {"imu": (3, 4, 5, 9, 10, 11), "depth": (2,), "dvl": (6, 7, 8), "position": (0, 1)}
SENSOR_WHAT = {"imu": "attitude phi theta psi and body rates p q r", "depth": "depth z from pressure",
               "dvl": "body velocity u v w (DVL)", "position": "horizontal position x y (USBL, motion capture)"}
COMPONENTS = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")


def sensor_set(cfg: ScenarioConfig) -> tuple[tuple[str, int], ...] | None:
    """The scenario's sensors as ``(name, every)``, ``every`` the controller samples between two fresh readings
    (1: every sample; a sensor faster than the controller is read once per sample, its newest reading), in
    :data:`SENSORS` order; None when the scenario names none: the whole ``[eta; nu]`` at every sample."""
    got = [(n, getattr(cfg, f"sensors_{n}_period")) for n in SENSORS]
    if all(p is None for _, p in got):
        return None
    return tuple((n, max(1, int(round(p / cfg.time_h)))) for n, p in got if p is not None)


def measured(cfg: ScenarioConfig) -> tuple[tuple[int, str, int], ...]:
    """The measurement vector, component by component: ``(index in [eta; nu], sensor, every)`` in the order of
    [eta; nu]; all twelve (sensor ``"state"``, every 1) when the scenario names no sensor set."""
    sset = sensor_set(cfg)
    if sset is None:
        return tuple((i, "state", 1) for i in range(12))
    by = {i: (n, every) for n, every in sset for i in SENSORS[n]}
    return tuple((i, *by[i]) for i in sorted(by))


def latencies(cfg: ScenarioConfig) -> tuple[tuple[str, int], ...]:
    """The fitted sensors whose readings lag, as ``(name, d)`` in :data:`SENSORS` order: a reading that arrives at
    sample k is the state of sample k - d (d >= 1 controller samples; docs/sensors.md). Empty when none lags."""
    out = []
    for n in SENSORS:
        lat = getattr(cfg, f"sensors_{n}_latency")
        if lat is not None and getattr(cfg, f"sensors_{n}_period") is not None and round(lat / cfg.time_h) > 0:
            out.append((n, int(round(lat / cfg.time_h))))
    return tuple(out)


def held_dofs(cfg: ScenarioConfig) -> tuple[bool, ...]:
    """The DOFs (x y z phi theta psi) the task holds: all six, or without a position sensor depth, attitude and
    heading (x, y drift: reported, not penalised; docs/sensors.md)."""
    sset = sensor_set(cfg)
    return (True,) * 6 if sset is None or "position" in dict(sset) else (False, False, True, True, True, True)


def _check_sensors(cfg: ScenarioConfig, where: str) -> None:
    """A sensor set observes what the task holds: IMU and depth always, a position fix for a trajectory (it moves
    the vehicle in x, y); each period is the controller's h or a whole multiple of it, or faster than h."""
    sset = sensor_set(cfg)
    if sset is None:
        _check_latencies(cfg, where, ())
        return
    names = dict(sset)
    for n in ("imu", "depth"):
        if n not in names:
            raise ScenarioError(f"{where}: sensors.{n}_period: missing: a sensor set needs the {n} "
                                f"({SENSOR_WHAT[n]}), which station keeping holds")
    if cfg.has_trajectory and "position" not in names:
        raise ScenarioError(f"{where}: sensors.position_period: missing: a trajectory task moves the vehicle in x, "
                            f"y, which a sensor set without a position fix cannot observe (without one the task is "
                            f"a depth, attitude and heading hold)")
    for n in names:
        p = getattr(cfg, f"sensors_{n}_period")
        r = p / cfg.time_h
        if r > 1 + 1e-9 and abs(r - round(r)) > 1e-9:
            raise ScenarioError(f"{where}: sensors.{n}_period: {p:g} s must be at most time.h ({cfg.time_h:g} s) or "
                                f"a whole multiple of it (the controller reads its sensors at its own samples)")
    _check_latencies(cfg, where, names)


def _check_latencies(cfg: ScenarioConfig, where: str, fitted) -> None:
    """Each latency belongs to a fitted sensor and is a whole number of controller samples, 0 to MAX_LATENCY."""
    for n in SENSORS:
        lat = getattr(cfg, f"sensors_{n}_latency")
        if lat is None:
            continue
        if n not in fitted:
            raise ScenarioError(f"{where}: sensors.{n}_latency: the {n} sensor is not fitted (no sensors.{n}_period): "
                                f"give its period or remove its latency")
        r = lat / cfg.time_h
        if abs(r - round(r)) > 1e-9 or round(r) > MAX_LATENCY:
            raise ScenarioError(f"{where}: sensors.{n}_latency: {lat:g} s must be a whole multiple of time.h "
                                f"({cfg.time_h:g} s), from 0 to {MAX_LATENCY} samples ({MAX_LATENCY * cfg.time_h:g} s)")


def _check_current(cfg: ScenarioConfig, where: str) -> None:
    """A current table covers every depth at every time, once (no gaps, no duplicates)."""
    if cfg.current != "table":
        return
    ts, zs = cfg.current_grid
    seen: dict = {}
    for j, p in enumerate(cfg.current_point, start=1):
        if (p.t, p.depth) in seen:
            raise ScenarioError(f"{where}: current.point[{j}]: t = {p.t:g} s, depth = {p.depth:g} m is also point "
                                f"{seen[(p.t, p.depth)]}")
        seen[(p.t, p.depth)] = j
    for t in ts:
        for z in zs:
            if (t, z) not in seen:
                raise ScenarioError(f"{where}: current.point: a gap: no point at t = {t:g} s, depth = {z:g} m (the "
                                    f"table has times {', '.join(f'{x:g}' for x in ts)} s and depths "
                                    f"{', '.join(f'{x:g}' for x in zs)} m: every depth at every time)")


def _num(v) -> str:
    if isinstance(v, str):
        return '"' + v + '"'  # a pattern or segment name (one of the schema's choices)
    if isinstance(v, int) and not isinstance(v, bool):
        return repr(v)
    return "[" + ", ".join(repr(float(x)) for x in v) + "]" if isinstance(v, tuple) else repr(float(v))


def _get(obj, attrs):
    for a in attrs:
        if obj is None:
            return None
        obj = getattr(obj, a)
    return obj


_PAPER_ARM = ("qg", "hold_until", "reach_end", "payload_on", "payload_ramp", "return_start", "return_end")


def _check_motion(cfg: ScenarioConfig, where: str) -> None:
    """Exactly one form of arm motion, with its times in order; or none (no ``[arm]`` section, or an empty one:
    the arm, if the system has one, holds its stow pose, and a system without an arm needs nothing)."""
    given = [k for k in _PAPER_ARM if getattr(cfg, "arm_" + k) is not None]
    if cfg.arm_waypoint is None and not given:
        if cfg.payload_event is not None:
            raise ScenarioError(f"{where}: payload.event: a payload is carried by the arm: give [[arm.waypoint]] "
                                f"tables with it")
        return
    if cfg.arm_waypoint is None:
        missing = [k for k in _PAPER_ARM if k not in given]
        if missing:
            raise ScenarioError(f"{where}: arm.{missing[0]}: missing (give the paper's reach-and-return keys "
                                f"{', '.join(_PAPER_ARM)}, or [[arm.waypoint]] tables)")
        if cfg.payload_event is not None:
            raise ScenarioError(f"{where}: payload.event: the paper's form ramps the payload by arm.payload_on and "
                                f"arm.payload_ramp; [[payload.event]] goes with [[arm.waypoint]]")
        if not (cfg.arm_hold_until < cfg.arm_reach_end <= cfg.arm_return_start < cfg.arm_return_end):
            raise ScenarioError(f"{where}: arm times must satisfy hold_until < reach_end <= return_start < return_end")
        return
    if given:
        raise ScenarioError(f"{where}: arm.{given[0]}: not with [[arm.waypoint]] (one form of arm motion: the "
                            f"paper's keys or waypoints)")
    ws = cfg.arm_waypoint
    for j, w in enumerate(ws, start=1):
        if j > 1 and not w.t > ws[j - 2].t:
            raise ScenarioError(f"{where}: arm.waypoint[{j}].t: {w.t:g} s must be after waypoint {j - 1}'s "
                                f"{ws[j - 2].t:g} s")
    sizes = {len(w.q) for w in ws if not w.stow}
    if len(sizes) > 1:
        raise ScenarioError(f"{where}: arm.waypoint: every q must have the same number of angles, got {sorted(sizes)}")
    ev = cfg.payload_event or ()
    for j, e in enumerate(ev, start=1):
        if j > 1 and not e.t >= ev[j - 2].t + ev[j - 2].ramp:
            raise ScenarioError(f"{where}: payload.event[{j}].t: {e.t:g} s starts before event {j - 1}'s ramp ends "
                                f"({ev[j - 2].t + ev[j - 2].ramp:g} s)")


def n_samples(cfg: ScenarioConfig) -> int:
    """Controller samples k = 0..N with t_k = k h, N = duration / h: returns N + 1."""
    return int(round(cfg.time_duration / cfg.time_h)) + 1
