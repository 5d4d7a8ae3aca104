"""Logs of a real vehicle: a mapping file (``*.log.toml``) -> streams aligned on one time base in the model's frames.

A log is a set of time-stamped streams (motion-capture or navigation pose, IMU attitude and rates, DVL
velocities, depth, joint positions, thrust or thruster commands, payload). The mapping file (docs/logs.md) says which CSV file
(or which ROS bag topic, or which ArduPilot log message: :mod:`arvcas.ident.ardupilot`) and which columns (or
message fields) give which signal, in which unit and
frame. :func:`load_log` reads it, checks every stream before any work (one line naming the file, the column
and the reason: time not increasing, a gap longer than allowed, NaN, an unknown unit, a frame that does
not match) and returns a :class:`Log`:

* the common time base: ``t`` from 0 at the latest start of the streams to the earliest end, at
  ``[log] rate`` (default 50 Hz), each stream linearly interpolated onto it;
* positions in the NED world frame, the body frame FRD (x forward, y starboard, z down), attitude as
  ZYX Euler angles ``roll, pitch, yaw`` from the rotation matrix, unwrapped (no 2 pi jumps);
* the joints as one smoothing spline per joint (:func:`scipy.interpolate.make_smoothing_spline`):
  positions, rates and accelerations at any time. The smoothing is stated as a frequency: minimising
  ``sum (q_i - s(t_i))^2 + lam int s''(t)^2 dt`` over samples ``dt`` apart filters a sinusoid of angular
  frequency ``w`` by ``1 / (1 + lam dt w^4)``, so ``lam = 1 / (dt (2 pi f_c)^4)`` halves the amplitude at
  ``f_c = [log] joint_cutoff`` (default 2 Hz: an arm's quintic moves of a second or more pass, encoder
  noise is removed before it is differentiated twice). Generalised cross-validation was measured at 1.1 s
  per joint of 2,000 samples and is not used.

Frames: ``world = "ned" | "enu" | "nwu"`` (ROS's ENU; NWU is any z-up frame with x along the pool's
axis, turned to NED by a half turn about x) and ``body = "frd" | "flu"`` (ROS's base_link). A quaternion
is the body's attitude in the world frame (it maps body vectors to world vectors), in the column order
``quaternion_order``. ``point`` is where on the body (FRD, m, from the body origin) a position is measured.
``depth`` is the vertical coordinate alone (a pressure sensor, or a pose whose horizontal frame differs
from the attitude's), in the stream's world frame: a z-up height becomes NED's z = -height.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from arvcas.system import config
from arvcas.system.config import Choices, Count, Invalid, Unique, ge, gt, le, quantity, setting
from arvcas.system.systemfile import COMMAND_UNITS
from arvcas.ident.rotations import BLOCK_ROWS, R_from_euler, R_from_quaternion, _attitude, _slices, euler_from_R  # euler_from_R: public here too
from arvcas.ident.streams import MAX_MEMORY_MB, Budget, LogError, Table, read_bag, read_csv

__all__ = ["LogError", "Log", "JointTrajectory", "load_log", "load_logs", "MAPPING_SUFFIX", "SIGNALS",
           "euler_from_R", "R_from_euler", "WORLD_FRAMES", "BODY_FRAMES"]

MAPPING_SUFFIX = ".log.toml"
MAX_GRID = 5_000_000  # samples of the common time base
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
# vectors in the source frame -> NED world / FRD body (each matrix is its own inverse)
WORLD_FRAMES = {"ned": np.eye(3), "enu": np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]),
                "nwu": np.diag([1.0, -1, -1])}
BODY_FRAMES = {"frd": np.eye(3), "flu": np.diag([1.0, -1, -1])}
# the model's measured signals, in this order (eta then nu; joints follow by name)
SIGNALS = ("x", "y", "z", "roll", "pitch", "yaw", "u", "v", "w", "p", "q", "r")
_KINDS = {  # mapping key -> (number of columns, dimension of each column)
    "position": (3, "length"), "quaternion": (4, "1"), "euler": (3, "angle"), "depth": (1, "length"),
    "velocity": (3, "velocity"), "angular_velocity": (3, "angular_velocity"),
    "acceleration": (3, "acceleration"),
    "wrench": (6, ("force", "force", "force", "torque", "torque", "torque")), "payload": (1, "1"),
    "pressure": (1, "pressure"),
}
# the autopilot messages whose output channels ``outputs`` names, and each channel's field
_OUTPUT_FIELDS = {"RCOU": "C{}", "SERVO_OUTPUT_RAW": "servo{}_raw"}
_ROLL_LIMIT_DEG = 90.0  # a vehicle whose median roll is beyond this is read in the wrong body frame


# ---- the mapping file's schema (arvcas.system.config: each rule beside its field) ------------------------------


@dataclass(frozen=True)
class SignalMap:
    """Columns (CSV) or message fields (bag) of one signal, their unit and, optionally, its noise."""

    columns: tuple[str, ...] = setting(Unique(), Count(1, 6), required=True, scalar_ok=True)
    unit: str = setting(default="SI")  # one unit for every column, or one per column ("N,N,N,N*m,N*m,N*m")
    std: float | None = quantity("1", gt(0), default=None)  # measurement noise, in the signal's unit


@dataclass(frozen=True)
class JointMap:
    """One joint's position column: model angle = sign * (column * unit) + offset."""

    column: str = setting(required=True)
    unit: str = setting(default="rad")
    offset: float = quantity("angle", default=0.0, unit="rad")
    sign: int = setting(default=1)
    std: float | None = quantity("angle", gt(0), default=None, unit="rad")

    def _config_check(self, given):
        if self.sign not in (1, -1):
            raise Invalid("sign", f"must be 1 or -1, got {self.sign!r}")


@dataclass(frozen=True)
class StreamMap:
    """One CSV file (``file``), one bag topic (``topic``) or one ArduPilot log message (``message``) and the
    signals it gives."""

    file: str | None = setting(default=None)
    topic: str | None = setting(default=None)
    message: str | None = setting(default=None)  # an ArduPilot log's message ("ATT", "SERVO_OUTPUT_RAW")
    instance: int | None = setting(default=None)  # a DataFlash message's instance (IMU, BARO: field I)
    # CSV: the time column; bag: a field ("header.stamp"), else log time; ArduPilot: the boot clock's field
    time: str | None = setting(default=None)
    time_unit: str = setting(Choices(tuple(TIME_UNITS), "time unit"), default="s")
    time_offset: float = quantity("time", default=0.0, unit="s")  # added to this stream's times
    world: str = setting(Choices(tuple(WORLD_FRAMES), "world frame"), default="ned")
    body: str = setting(Choices(tuple(BODY_FRAMES), "body frame"), default="frd")
    point: tuple[float, float, float] | None = quantity("length", n=3, default=None, unit="m")
    quaternion_order: str = setting(Choices(("xyzw", "wxyz"), "quaternion order"), default="xyzw")
    position: SignalMap | None = setting(default=None)
    quaternion: SignalMap | None = setting(default=None)
    euler: SignalMap | None = setting(default=None)
    depth: SignalMap | None = setting(default=None)
    velocity: SignalMap | None = setting(default=None)
    angular_velocity: SignalMap | None = setting(default=None)
    acceleration: SignalMap | None = setting(default=None)
    wrench: SignalMap | None = setting(default=None)
    payload: SignalMap | None = setting(default=None)
    pressure: SignalMap | None = setting(default=None)  # absolute pressure -> depth (density, surface_pressure)
    density: float | None = quantity("density", gt(0), default=None, unit="kg/m^3")  # of the water
    surface_pressure: float | None = quantity("pressure", gt(0), default=None, unit="Pa")  # pressure at depth 0
    gravity: float = quantity("acceleration", gt(0), default=config.STANDARD_GRAVITY, unit="m/s^2")
    # ArduPilot: output channel k (1-based) drives the system's thruster outputs[k - 1] ("" for none)
    outputs: tuple[str, ...] | None = setting(Count(1, 32), default=None)
    thrust: dict[str, SignalMap] | None = setting(default=None)  # thruster name -> its thrust column
    command: dict[str, SignalMap] | None = setting(default=None)  # thruster name -> the command sent to it
    joints: dict[str, JointMap] | None = setting(default=None)  # "q1".."qn" -> its column

    def _config_check(self, given):
        if sum(x is not None for x in (self.file, self.topic, self.message)) != 1:
            raise Invalid(None, "a stream gives exactly one of `file` (a CSV file), `topic` (a bag topic) or "
                                "`message` (an ArduPilot log's message)")
        if self.file is not None and self.time is None:
            raise Invalid("time", "a CSV stream names its time column")
        if self.message is None:
            for k in ("instance", "outputs"):
                if getattr(self, k) is not None:
                    raise Invalid(k, "belongs to an ArduPilot log's `message` stream")
        else:
            for k in ("time", "time_unit"):
                if k in given:
                    raise Invalid(k, "an ArduPilot message's time is the autopilot's boot clock (TimeUS, time_boot_ms "
                                     "or time_usec): drop it")
        if self.outputs is not None:
            if self.message not in _OUTPUT_FIELDS:
                raise Invalid("outputs", f"names the output channels of {' or '.join(_OUTPUT_FIELDS)} (message = "
                                         f"{self.message!r}: map its fields with `command`)")
            if self.command is not None:
                raise Invalid("outputs", "give the thrusters' commands once: `outputs` or `command`")
            named = [n for n in self.outputs if n]
            if not named:
                raise Invalid("outputs", "names no thruster")
            dup = next((n for n in named if named.count(n) > 1), None)
            if dup is not None:
                raise Invalid("outputs", f"thruster {dup!r} is driven by two channels "
                                         f"({', '.join(str(k + 1) for k, n in enumerate(self.outputs) if n == dup)})")
        if self.pressure is not None:
            for k in ("density", "surface_pressure"):
                if getattr(self, k) is None:
                    raise Invalid(k, "depth from pressure needs the water's density (kg/m^3) and the surface "
                                     "pressure (Pa) in the stream: depth = (p - surface_pressure) / (density g)")
            if self.depth is not None:
                raise Invalid("pressure", "a stream gives its depth once: `depth` or `pressure`")
        if not any(getattr(self, k) is not None for k in (*_KINDS, "thrust", "command", "outputs", "joints")):
            raise Invalid(None, "the stream maps no signal (position, quaternion, euler, depth, pressure, velocity, "
                                "angular_velocity, acceleration, wrench, payload, thrust, command, outputs, joints)")
        if self.quaternion is not None and self.euler is not None:
            raise Invalid("euler", "a stream gives its attitude once: `quaternion` or `euler`")


@dataclass(frozen=True)
class LogInfo:
    name: str | None = setting(default=None)
    system: str | None = setting(default=None)  # the system the vehicle is (a shipped name or a file)
    source: str = setting(default="")
    bag: str | None = setting(default=None)  # a ROS 2 bag directory (MCAP or sqlite3) or ROS 1 .bag, from this file
    ardupilot: str | None = setting(default=None)  # an ArduPilot log (.bin DataFlash, .tlog MAVLink), from this file
    segment: str | None = setting(Choices(("armed", "all"), "segment"), default=None)  # ArduPilot: default armed
    modes: tuple[str, ...] | None = setting(Count(1, 32), default=None)  # armed in one of these flight modes
    segment_index: int | None = setting(default=None)  # 1-based, of the segments that match
    rate: float = quantity("1", gt(0), le(10_000.0), default=50.0)  # Hz: the common time base
    max_gap: float = quantity("time", gt(0), default=0.5, unit="s")
    t_start: float = quantity("time", ge(0), default=0.0, unit="s")  # after the common start
    t_end: float | None = quantity("time", gt(0), default=None, unit="s")
    passive: bool = setting(default=False)  # no thrust logged: the thrusters were off (zero thrust)
    joint_cutoff: float = quantity("1", gt(0), default=2.0)  # Hz: where the joint splines halve an amplitude
    # the arm held still at these angles (rad, q1..qn) through the log: no joint stream (an autopilot's log)
    held_joints: tuple[float, ...] | None = quantity("angle", n=config.ANY_LENGTH, default=None, unit="rad")
    # MB (10^6 bytes) the values read from the log's files may take (float64): more is refused before it is read
    max_memory_mb: float = quantity("1", gt(0), default=MAX_MEMORY_MB)

    def _config_check(self, given):
        if self.t_end is not None and self.t_end <= self.t_start:
            raise Invalid("t_end", f"must be after t_start ({self.t_start:g} s)")
        if self.name is not None and not re.fullmatch(r"[A-Za-z0-9_.+-]{1,64}", self.name):
            raise Invalid("name", "letters, digits and _ . + - only (at most 64)")
        if self.ardupilot is None:
            for k in ("segment", "modes", "segment_index"):
                if getattr(self, k) is not None:
                    raise Invalid(k, "cuts an ArduPilot log: needs [log] ardupilot = \"<.bin or .tlog file>\"")
        if self.modes is not None and self.segment == "all":
            raise Invalid("modes", "picks armed stretches in these modes: not with segment = \"all\"")
        if self.segment_index is not None and self.segment_index < 1:
            raise Invalid("segment_index", f"counts from 1, got {self.segment_index}")


@dataclass(frozen=True)
class LogMapping:
    log: LogInfo = setting(default_factory=LogInfo)
    stream: tuple[StreamMap, ...] = setting(Count(1, 64), default=(), required=True)


# ---- results --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class JointTrajectory:
    """Smoothing splines of the joint positions (model angles, rad), one per joint, on the log's time (s)."""

    names: tuple[str, ...]
    splines: tuple[Any, ...]  # scipy BSpline, degree 3 (natural cubic smoothing spline)
    smoothing: tuple[float, ...]  # the penalty lam each spline was fitted with
    cutoff: float  # Hz: the frequency whose amplitude lam halves
    raw_t: tuple[np.ndarray, ...]
    raw_q: tuple[np.ndarray, ...]

    def __call__(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, qd, qdd) at times ``t`` (s), each of shape ``t.shape + (n_joints,)``."""
        t = np.asarray(t, dtype=float)
        out = [np.stack([s(t, nu=k) for s in self.splines], axis=-1) for k in (0, 1, 2)]
        return out[0], out[1], out[2]

    def fit_rms(self) -> tuple[float, ...]:
        """RMS of the raw positions minus the spline, per joint (rad): what the smoothing removed."""
        return tuple(float(np.sqrt(np.mean((s(t) - q) ** 2))) for s, t, q in zip(self.splines, self.raw_t, self.raw_q))


@dataclass(frozen=True)
class Log:
    """One trial: signals on a common time base in the model's frames (SI: m, rad, m/s, rad/s, N)."""

    name: str
    path: str  # the mapping file
    system: str | None
    source: str
    t: np.ndarray  # (N,) s, from 0
    t0: float  # the common start on the streams' own clock (s)
    signals: dict[str, np.ndarray]  # SIGNALS present and joint names -> (N,)
    std: dict[str, float]  # stated measurement noise (SI) of the signals that give one
    joints: JointTrajectory | None
    thrust: dict[str, np.ndarray]  # thruster name -> (N,) N
    command: dict[str, np.ndarray]  # thruster name -> (N,) the command sent (its map's unit), held between messages
    command_unit: dict[str, str]  # thruster name -> the unit of its command (us, 1, rad/s)
    wrench: np.ndarray | None  # (N, 6) body wrench at the body origin: N, N m
    payload: np.ndarray | None  # (N,) fraction of the system's payload
    passive: bool
    files: tuple[str, ...]  # every stream file read
    segment: str | None = None  # an ArduPilot log's segment: boot-clock start and end (s), flight modes

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def measured(self) -> list[str]:
        """The model signals this log measures, in :data:`SIGNALS` order then the joints."""
        return [s for s in SIGNALS if s in self.signals] + [j for j in (self.joints.names if self.joints else ())]

    def window(self, t_start: float, t_end: float) -> "Log":
        """The part of the log in [t_start, t_end] (s of :attr:`t`), its time again from 0."""
        k = (self.t >= t_start - 1e-9) & (self.t <= t_end + 1e-9)
        if k.sum() < 2:
            raise LogError(f"{self.path}: window [{t_start:g}, {t_end:g}] s holds fewer than 2 samples")
        i0 = int(np.argmax(k))
        sl = lambda a: None if a is None else a[k]  # noqa: E731
        jt = None
        if self.joints is not None:
            shift = self.t[i0]
            jt = _shifted(self.joints, shift)
        return dataclasses.replace(
            self, t=self.t[k] - self.t[i0], t0=self.t0 + float(self.t[i0]),
            signals={n: v[k] for n, v in self.signals.items()}, joints=jt,
            thrust={n: v[k] for n, v in self.thrust.items()}, command={n: v[k] for n, v in self.command.items()},
            wrench=sl(self.wrench), payload=sl(self.payload))


def _shifted(jt: JointTrajectory, shift: float) -> JointTrajectory:
    from scipy.interpolate import BSpline

    sp = tuple(BSpline(s.t - shift, s.c, s.k) for s in jt.splines)
    return dataclasses.replace(jt, splines=sp, raw_t=tuple(t - shift for t in jt.raw_t))


# ---- reading a stream ---------------------------------------------------------------------------------



def _check_quaternion_order(sm, quaternions, n: int, acc, Cw, Cb, what: str, block: int = BLOCK_ROWS) -> None:
    """The quaternion's component order, checked against the accelerometer of the same stream (``acc``; no
    check without one): the direction of its specific force (at rest ``-R^T g``, up in the body: ``-R[2, :]``)
    against the attitude's, median over the rows. Refused when the order given is more than 20 deg off and
    the other order within 10 deg. (The tilt alone cannot tell: a body frame given wrong tilts the vehicle
    too, and the other order can look level by chance.) ``quaternions(s)``: the unit quaternions of the rows
    ``s`` (a slice) as read, x, y, z, w; a block of rows at a time."""
    if acc is None:
        return
    other = "wxyz" if sm.quaternion_order == "xyzw" else "xyzw"
    f = acc @ Cb.T
    nf = np.linalg.norm(f, axis=1)
    off = np.empty((2, n))  # rad: the order given, the other
    for s in _slices(n, block):
        q = quaternions(s)
        raw = q[:, [3, 0, 1, 2]] if sm.quaternion_order == "wxyz" else q  # the columns as the file has them
        for k, qk in enumerate((q, raw[:, [1, 2, 3, 0]] if other == "wxyz" else raw)):
            Rm = Cw @ R_from_quaternion(qk) @ Cb
            c = np.einsum("ni,ni->n", f[s], -Rm[:, 2, :]) / np.where(nf[s] > 0, nf[s], 1.0)
            off[k, s] = np.arccos(np.clip(c, -1.0, 1.0))
    given, alt = (float(np.degrees(np.median(o))) for o in off)
    if given > 20.0 and alt < 10.0:
        raise LogError(f"{what} = \"{sm.quaternion_order}\" looks wrong: the accelerometer's gravity direction is "
                       f"{given:.0f} deg from the attitude's (median); with \"{other}\" it is {alt:.0f} deg")


_MOTOR_FUNCTIONS = {**{33 + k: k + 1 for k in range(8)}, **{82 + k: k + 9 for k in range(4)}}  # SERVOn_FUNCTION


def _read_ardupilot(path: Path, m: LogMapping, info: LogInfo, where: str, budget: Budget):
    """(the autopilot's log with every message the streams name, the segment the mapping picks)."""
    from arvcas.ident import ardupilot
    from arvcas.util.files import check_input

    p = check_input(path, "ArduPilot log", LogError)
    wanted: dict[str, set[str]] = {}
    for sm in m.stream:
        if sm.message is not None:
            wanted.setdefault(sm.message, set()).update(_columns_of(sm))
    try:
        alog = ardupilot.read(p, wanted, where, budget)
        segs = ardupilot.segments(alog, info.segment or "armed", info.modes)
    except ardupilot.Error as e:
        raise LogError(str(e)) from None
    what = "armed" + (f" in {', '.join(info.modes)}" if info.modes else "") if info.segment != "all" else "whole"
    if not segs:
        raise LogError(f"{p}: no segment {what} (modes logged: "
                       f"{', '.join(sorted({ardupilot.mode_name(c[2]) for c in alog.changes})) or 'none'})")
    if info.segment_index is None and len(segs) > 1:
        listed = "; ".join(f"{k + 1}: {sg}" for k, sg in enumerate(segs))
        raise LogError(f"{where}: {len(segs)} segments {what} in {p.name} ({listed}): pick one with "
                       f"[log] segment_index")
    k = (info.segment_index or 1) - 1
    if k >= len(segs):
        raise LogError(f"{where}: [log] segment_index = {k + 1}, but {p.name} has {len(segs)} segment(s) {what}")
    for i, sm in enumerate(m.stream):
        if sm.message is None:
            continue
        key = f"stream[{i + 1}]"
        units = alog.units.get(sm.message, {})
        maps = [(kd, getattr(sm, kd)) for kd in _KINDS if getattr(sm, kd) is not None]
        maps += [(f"command.{tn}", s) for tn, s in _commands_of(sm).items()]
        for kd, s in maps:  # a column's unit against the one the log states for its field
            us = [u.strip() for u in s.unit.split(",")]
            for c, u in zip(s.columns, us * len(s.columns) if len(us) == 1 else us):
                said = ardupilot.LOG_UNITS.get(units.get(c.split("[", 1)[0], ""))
                if said is None:
                    continue
                ok = config.UNITS[said][1] == 1.0 if u == config.SI else (
                    u in config.UNITS and config.UNITS[u][0] == config.UNITS[said][0]
                    and math.isclose(config.UNITS[u][1], config.UNITS[said][1]))
                if not ok:
                    raise LogError(f"{where}: {key}.{kd}.unit: {sm.message}.{c} is in {said} (the log says so), "
                                   f"mapped as {u!r}")
        if sm.outputs is not None:
            for ch in range(1, 33):
                fn = alog.params.get(f"SERVO{ch}_FUNCTION")
                tn = sm.outputs[ch - 1] if ch <= len(sm.outputs) else ""
                if fn is None:
                    continue
                motor = _MOTOR_FUNCTIONS.get(int(fn))
                if tn and motor is None:
                    raise LogError(f"{where}: {key}.outputs: channel {ch} drives thruster {tn!r}, but the log's "
                                   f"SERVO{ch}_FUNCTION = {int(fn)} is not a motor")
                if motor is not None and not tn:
                    raise LogError(f"{where}: {key}.outputs: channel {ch} is the autopilot's motor {motor} "
                                   f"(SERVO{ch}_FUNCTION = {int(fn)}) but drives no thruster in the mapping")
    return alog, segs[k]


def _ardupilot_table(alog, sm: StreamMap, names: list[str], where: str) -> Table:
    from arvcas.ident import ardupilot

    try:
        t, cols = ardupilot.table(alog, sm.message, sm.instance, where)
    except ardupilot.Error as e:
        raise LogError(str(e)) from None
    inst = "" if sm.instance is None else f"[{sm.instance}]"
    if len(t) < 2:
        raise LogError(f"{alog.path}: message {sm.message}{inst}: fewer than 2 samples")
    back = np.flatnonzero(np.diff(t) < -1.0)
    if back.size:  # a clock that restarts: a second boot in one telemetry log
        i = int(back[0])
        raise LogError(f"{alog.path}: message {sm.message}{inst}: the boot clock restarts ({t[i + 1]:.3f} s after "
                       f"{t[i]:.3f} s): the autopilot rebooted; split the log at the reboot (one boot per log)")
    tf = "TimeUS" if alog.kind == "DataFlash" else "time_boot_ms or time_usec"
    return Table(f"{alog.path} message {sm.message}{inst}", t, tf, {n: cols[n] for n in names})


def _unit_factors(sm: SignalMap, n: int, dims, key: str, where: str) -> np.ndarray:
    units = [u.strip() for u in sm.unit.split(",")]
    if len(units) == 1:
        units = units * n
    if len(units) != n:
        raise LogError(f"{where}: {key}.unit: {len(units)} units for {n} columns")
    dims = dims if isinstance(dims, tuple) else (dims,) * n
    out = []
    for u, d in zip(units, dims):
        if u == config.SI:
            out.append(1.0)
            continue
        if u not in config.UNITS:
            allowed = [k for k, (dd, _) in config.UNITS.items() if dd == d] + [config.SI]
            raise LogError(f"{where}: {key}.unit: unknown unit {u!r} (allowed for a {d}: {', '.join(allowed)})")
        ud, f = config.UNITS[u]
        if ud != d:
            allowed = [k for k, (dd, _) in config.UNITS.items() if dd == d] + [config.SI]
            raise LogError(f"{where}: {key}.unit: {u!r} is not a unit of {d} (allowed: {', '.join(allowed)})")
        out.append(f)
    return np.array(out)


def _check_time(tab: Table, max_gap: float, scale: float) -> None:
    t = tab.time
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise LogError(f"{tab.where}: column {tab.time_name!r}: not a finite number in row {bad[0] + 2}")
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        i = bad[0]
        raise LogError(f"{tab.where}: column {tab.time_name!r}: time not increasing at row {i + 3} "
                       f"({t[i + 1]:.9g} after {t[i]:.9g})")


def _check_gaps(tab: Table, t: np.ndarray, lo: float, hi: float, max_gap: float) -> None:
    k = np.flatnonzero((t[1:] >= lo) & (t[:-1] <= hi))
    if k.size:
        d = t[k + 1] - t[k]
        j = int(np.argmax(d))
        if d[j] > max_gap:
            raise LogError(f"{tab.where}: column {tab.time_name!r}: a gap of {d[j]:.3g} s after t = {t[k[j]]:.6g} s "
                           f"(allowed: {max_gap:g} s, [log] max_gap)")


def _check_finite(tab: Table, names: list[str]) -> None:
    for n in names:
        bad = np.flatnonzero(~np.isfinite(tab.cols[n]))
        if bad.size:
            raise LogError(f"{tab.where}: column {n!r}: NaN or infinite value at row {bad[0] + 2} "
                           f"(t = {tab.time[bad[0]]:.6g} s)")


# ---- the log -----------------------------------------------------------------------------------------


def _commands_of(sm: StreamMap) -> dict[str, SignalMap]:
    """Thruster name -> its command's column: ``command``, or ``outputs`` (channel k -> RCOU's Ck, ...)."""
    if sm.outputs is None:
        return dict(sm.command or {})
    fmt = _OUTPUT_FIELDS[sm.message]
    return {tn: SignalMap(columns=(fmt.format(k + 1),), unit="us") for k, tn in enumerate(sm.outputs) if tn}


def _columns_of(sm: StreamMap) -> list[str]:
    names = []
    for k in _KINDS:
        s = getattr(sm, k)
        if s is not None:
            if len(s.columns) != _KINDS[k][0]:
                raise Invalid(f"{k}.columns", f"{_KINDS[k][0]} columns expected, got {len(s.columns)}")
            names += list(s.columns)
    for s in (*(sm.thrust or {}).values(), *_commands_of(sm).values()):
        if len(s.columns) != 1:
            raise Invalid("thrust" if s in (sm.thrust or {}).values() else "command",
                          f"one column per thruster, got {len(s.columns)}")
        names += list(s.columns)
    for j in (sm.joints or {}).values():
        names.append(j.column)
    return list(dict.fromkeys(names))


def _interp(tq: np.ndarray, t: np.ndarray, y: np.ndarray, block: int = BLOCK_ROWS) -> np.ndarray:
    """``np.interp`` of ``y`` (n,) or of each column of ``y`` (n, k) onto ``tq``, a block of ``tq`` at a time:
    NumPy's interp, given more points than samples, first computes every sample's slope (an array as long as
    the column); a block computes the slope of each point where it is used, the same expression: the same
    bits. What it costs is the result, a column's copy when ``y``'s are strided, and a block."""
    t = np.ascontiguousarray(t)
    out = np.empty(tq.shape + y.shape[1:])
    for i in range(1 if y.ndim == 1 else y.shape[1]):
        yi = np.ascontiguousarray(y if y.ndim == 1 else y[:, i])
        oi = out if y.ndim == 1 else out[:, i]
        for s in _slices(tq.size, block):
            oi[s] = np.interp(tq[s], t, yi)
    return out


def load_log(path: str | Path, n_joints: int | None = None, thruster_names: tuple[str, ...] | None = None) -> Log:
    """Read the mapping file ``path`` and every stream it names; :class:`LogError` (one line) on any fault.

    ``n_joints`` / ``thruster_names``: the system's, to check the mapped joints ("q1".."qn") and thrusters
    by name before any work (None: not checked).
    """
    from scipy.interpolate import make_smoothing_spline

    p = Path(path)
    where = str(p)
    m = config.load_file(LogMapping, p, LogError, what="log mapping file").value
    info = m.log
    base = p.parent
    name = info.name or (p.name[: -len(MAPPING_SUFFIX)] if p.name.endswith(MAPPING_SUFFIX) else p.stem)
    bag = None
    if info.bag is not None:
        from arvcas.util.files import check_input

        bag = check_input(base / info.bag, "ROS bag", LogError, allow_dir=True)
    # the mapping's own rules, before reading any stream
    seen: dict[str, str] = {}
    for i, sm in enumerate(m.stream):
        key = f"stream[{i + 1}]"  # 1-based, as arvcas.system.config numbers [[tables]]
        try:
            _columns_of(sm)
        except Invalid as e:
            raise LogError(f"{where}: {key}.{e.key}: {e.message}") from None
        if sm.topic is not None and bag is None:
            raise LogError(f"{where}: {key}.topic: a bag topic needs [log] bag = \"<bag directory>\"")
        if sm.message is not None and info.ardupilot is None:
            raise LogError(f"{where}: {key}.message: an ArduPilot message needs [log] ardupilot = \"<.bin or .tlog "
                           f"file>\"")
        if sm.outputs is not None and thruster_names is not None:
            free = [tn for tn in thruster_names if tn not in sm.outputs]
            if free:
                raise LogError(f"{where}: {key}.outputs: the system's thrusters {', '.join(free)} are driven by no "
                               f"output channel (outputs lists, for channel 1, 2, ..., the thruster it drives)")
        for k in _KINDS:
            s = getattr(sm, k)
            if s is not None:
                _unit_factors(s, _KINDS[k][0], _KINDS[k][1], f"{key}.{k}", where)
        for jn, jm in (sm.joints or {}).items():
            if n_joints == 0:
                raise LogError(f"{where}: {key}.joints.{jn}: the system has no arm: remove the joints from the "
                               f"mapping, or use a system with an arm")
            if n_joints is not None and jn not in [f"q{k}" for k in range(1, n_joints + 1)]:
                raise LogError(f"{where}: {key}.joints.{jn}: the system has joints q1..q{n_joints}")
            if jm.unit not in ("rad", "deg", config.SI):
                raise LogError(f"{where}: {key}.joints.{jn}.unit: unknown unit {jm.unit!r} (allowed: rad, deg, SI)")
        cmd_key = "command" if sm.outputs is None else "outputs"
        for kind, tns in (("thrust", sm.thrust or {}), (cmd_key, _commands_of(sm))):
            for tn in tns:
                if thruster_names is not None and tn not in thruster_names:
                    raise LogError(f"{where}: {key}.{kind}.{tn}: the system has no thruster {tn!r} "
                                   f"(it has {', '.join(thruster_names)})")
        for tn, s in _commands_of(sm).items():
            if s.unit not in (*COMMAND_UNITS, config.SI):
                raise LogError(f"{where}: {key}.command.{tn}.unit: unknown command unit {s.unit!r} "
                               f"(allowed: {', '.join(COMMAND_UNITS)}; SI means rad/s)")
        for sig in _signal_names(sm):
            if sig in seen:
                raise LogError(f"{where}: {key}: {sig} is also given by {seen[sig]}; map each signal once")
            seen[sig] = key
    if info.held_joints is not None:
        mapped = [k for k in seen if re.fullmatch(r"q\d+", k)]
        if mapped:
            raise LogError(f"{where}: [log] held_joints: {seen[mapped[0]]} maps joint {mapped[0]}: map the joints or "
                           f"hold them, not both")
        if n_joints is not None and len(info.held_joints) != n_joints:
            raise LogError(f"{where}: [log] held_joints: {len(info.held_joints)} angles for a system of {n_joints} "
                           f"joints")
    if n_joints is not None and n_joints > 0:
        missing = [f"q{k}" for k in range(1, n_joints + 1) if f"q{k}" not in seen]
        if missing and len(missing) < n_joints:
            raise LogError(f"{where}: joints {', '.join(missing)} are not mapped (map every joint or none)")
    if "thrust" in seen and "command" in seen:
        raise LogError(f"{where}: {seen['command']}: commands and thrust in one log: map the thrusters' commands "
                       f"(the plant runs them through the system's thruster dynamics) or their thrust, not both")
    if not any(k in seen for k in ("thrust", "command", "wrench")) and not info.passive:
        raise LogError(f"{where}: no thrust, command or wrench stream: map one, or say [log] passive = true "
                       f"(the thrusters were off)")
    alog, seg = None, None
    budget = Budget(where, info.max_memory_mb)  # what the streams' values may take, all together
    if info.ardupilot is not None:  # one pass over the autopilot's log: every message the streams name
        alog, seg = _read_ardupilot(base / info.ardupilot, m, info, where, budget)
    # read every stream, check its time, find the common window
    tabs = []
    for i, sm in enumerate(m.stream):
        names = _columns_of(sm)
        if sm.file is not None:
            tab = read_csv(base / sm.file, names, sm.time, where, budget)
        elif sm.topic is not None:
            tab = read_bag(bag, sm.topic, names, sm.time, where, budget)
        else:
            tab = _ardupilot_table(alog, sm, names, f"{where} stream[{i + 1}]")
        tab.time = tab.time * (1.0 if sm.message is not None else TIME_UNITS[sm.time_unit]) + sm.time_offset
        _check_time(tab, info.max_gap, 1.0)
        _check_finite(tab, names)
        tabs.append(tab)
    lo = max(float(tb.time[0]) for tb in tabs)
    hi = min(float(tb.time[-1]) for tb in tabs)
    if hi <= lo:
        spans = ", ".join(f"{tb.where}: {tb.time[0]:.6g}-{tb.time[-1]:.6g} s" for tb in tabs)
        raise LogError(f"{where}: the streams do not overlap in time ({spans})")
    if seg is not None:  # the segment of the autopilot's log, on its boot clock
        if min(hi, seg.end) - max(lo, seg.start) <= 0:
            raise LogError(f"{where}: the streams ({lo:.3f}-{hi:.3f} s) do not reach into the segment {seg}")
        lo, hi = max(lo, seg.start), min(hi, seg.end)
    t_lo = lo + info.t_start
    t_hi = hi if info.t_end is None else min(hi, lo + info.t_end)
    if t_hi - t_lo < 2.0 / info.rate:
        raise LogError(f"{where}: [log] t_start/t_end leave {max(t_hi - t_lo, 0):.3g} s of the streams' "
                       f"common {hi - lo:.3g} s")
    n = int(math.floor((t_hi - t_lo) * info.rate + 1e-9)) + 1
    if n > MAX_GRID:
        raise LogError(f"{where}: {n} samples at [log] rate = {info.rate:g} Hz (at most {MAX_GRID})")
    grid = t_lo + np.arange(n) / info.rate
    for tb in tabs:
        _check_gaps(tb, tb.time, t_lo, t_hi, info.max_gap)
    signals: dict[str, np.ndarray] = {}
    std: dict[str, float] = {}
    thrust: dict[str, np.ndarray] = {}
    command: dict[str, np.ndarray] = {}
    command_unit: dict[str, str] = {}
    wrench = payload = None
    jt_names, jt_t, jt_q, jt_std = [], [], [], {}
    for i, (sm, tb) in enumerate(zip(m.stream, tabs)):
        key = f"stream[{i + 1}]"  # 1-based, as arvcas.system.config numbers [[tables]]
        Cw, Cb = WORLD_FRAMES[sm.world], BODY_FRAMES[sm.body]

        def cols(k, rows=slice(None), sm=sm, tb=tb, key=key):
            s = getattr(sm, k)
            f = _unit_factors(s, _KINDS[k][0], _KINDS[k][1], f"{key}.{k}", where)
            v = np.stack([tb.cols[c][rows] for c in s.columns], axis=1, dtype=float)
            v *= f
            return v, (None if s.std is None else s.std * f[0])

        def quaternions(rows, sm=sm, tb=tb):  # unit, x y z w; a row that is not a unit quaternion is refused
            qv, _ = cols("quaternion", rows)
            if sm.quaternion_order == "wxyz":
                qv = qv[:, [1, 2, 3, 0]]
            nrm = np.linalg.norm(qv, axis=1)
            bad = np.flatnonzero(np.abs(nrm - 1.0) > 0.05)
            if bad.size:
                raise LogError(f"{tb.where}: columns {', '.join(sm.quaternion.columns)}: not a unit quaternion at "
                               f"row {(rows.start or 0) + bad[0] + 2} (norm {nrm[bad[0]]:.4g})")
            qv /= nrm[:, None]
            return qv

        att = None  # (the parameters of rows, their rotation matrices' function)
        n_tb = tb.time.size
        if sm.quaternion is not None:
            att = (quaternions, R_from_quaternion)
        elif sm.euler is not None:
            att = ((lambda rows, cols=cols: cols("euler", rows)[0]), R_from_euler)
            s_e = cols("euler", slice(0, 1))[1]
        arm = None  # R @ point, world frame
        if att is not None:
            rows, f_R = att
            e, arm = _attitude(rows, n_tb, f_R, Cw, Cb, None if sm.position is None or sm.point is None
                               else np.array(sm.point))
            if sm.quaternion is not None:
                _check_quaternion_order(sm, quaternions, n_tb, cols("acceleration")[0] if sm.acceleration is not None
                                        else None, Cw, Cb, f"{tb.where}: {where} {key}.quaternion_order")
            med = np.degrees(np.median(np.abs(e[0]), overwrite_input=True))
            if med > _ROLL_LIMIT_DEG:
                other = "flu" if sm.body == "frd" else "frd"
                alt = np.degrees(np.median(np.abs(_attitude(rows, n_tb, f_R, Cw, BODY_FRAMES[other])[0][0])))
                raise LogError(f"{tb.where}: the attitude's frame does not match: median roll {med:.0f} deg with "
                               f"body = \"{sm.body}\" in {where} {key} (body = \"{other}\" gives {alt:.0f} deg)")
            for k, nm in enumerate(("roll", "pitch", "yaw")):
                signals[nm] = _interp(grid, tb.time, e[k])
                e[k] = None  # (gone once used)
            if sm.euler is not None and sm.euler.std is not None:
                std.update(roll=s_e, pitch=s_e, yaw=s_e)
            if sm.quaternion is not None and sm.quaternion.std is not None:
                std.update(roll=sm.quaternion.std, pitch=sm.quaternion.std, yaw=sm.quaternion.std)
        if sm.position is not None:
            pv, s_p = cols("position")
            pv = pv @ Cw.T
            if sm.point is not None:
                if arm is None:
                    raise LogError(f"{where}: {key}.point: needs the attitude in the same stream")
                pv = pv - arm
            pv = _interp(grid, tb.time, pv)
            for k, nm in enumerate(("x", "y", "z")):
                signals[nm] = pv[:, k]
                if s_p is not None:
                    std[nm] = s_p
        if sm.depth is not None:  # the vertical coordinate alone, in the stream's world frame (z down in NED)
            dv, s_d = cols("depth")
            signals["z"] = _interp(grid, tb.time, Cw[2, 2] * dv[:, 0])
            if s_d is not None:
                std["z"] = s_d
        if sm.pressure is not None:  # hydrostatic: p = surface_pressure + density g depth
            pv, s_pr = cols("pressure")
            rg = sm.density * sm.gravity
            signals["z"] = _interp(grid, tb.time, (pv[:, 0] - sm.surface_pressure) / rg)
            if s_pr is not None:
                std["z"] = s_pr / rg
        for k_map, nms in (("velocity", ("u", "v", "w")), ("angular_velocity", ("p", "q", "r"))):
            if getattr(sm, k_map) is not None:
                v, s_v = cols(k_map)
                v = _interp(grid, tb.time, v @ Cb.T)
                for k, nm in enumerate(nms):
                    signals[nm] = v[:, k]
                    if s_v is not None:
                        std[nm] = s_v
        if sm.acceleration is not None:
            a, _ = cols("acceleration")
            a = (a @ Cb.T)[(tb.time >= t_lo) & (tb.time <= t_hi)]
            fz = float(np.mean(a[:, 2])) if len(a) else 0.0
            if fz > 0:
                raise LogError(f"{tb.where}: the accelerometer's frame does not match: mean specific force along "
                               f"body z is {fz:+.3g} m/s^2 with body = \"{sm.body}\" in {where} {key} (at rest it "
                               f"points up: negative in FRD)")
        if sm.wrench is not None:
            wv, _ = cols("wrench")
            wv = np.concatenate([wv[:, :3] @ Cb.T, wv[:, 3:] @ Cb.T], axis=1)
            wrench = _interp(grid, tb.time, wv)
        if sm.payload is not None:
            pl, _ = cols("payload")
            payload = _interp(grid, tb.time, pl[:, 0])
            if np.any((payload < 0) | (payload > 1)):
                raise LogError(f"{tb.where}: column {sm.payload.columns[0]!r}: payload fraction outside [0, 1]")
        for tn, s in (sm.thrust or {}).items():
            f = _unit_factors(s, 1, "force", f"{key}.thrust.{tn}", where)
            thrust[tn] = _interp(grid, tb.time, tb.cols[s.columns[0]] * f[0])
        for tn, s in _commands_of(sm).items():  # an autopilot's command holds until the next one
            # (a command logged within 1 ns of a sample, a clock's rounding, counts as at it)
            k = np.clip(np.searchsorted(tb.time, grid + 1e-9, side="right") - 1, 0, tb.time.size - 1)
            command[tn] = tb.cols[s.columns[0]][k]
            command_unit[tn] = "rad/s" if s.unit == config.SI else s.unit
        for jn, jm in sorted((sm.joints or {}).items(), key=lambda kv: int(kv[0][1:]) if kv[0][1:].isdigit() else 0):
            fac = math.pi / 180.0 if jm.unit == "deg" else 1.0
            qv = jm.sign * tb.cols[jm.column] * fac + jm.offset
            k = (tb.time >= t_lo - 1.0) & (tb.time <= t_hi + 1.0)  # a margin for the spline's ends
            jt_names.append(jn)
            jt_t.append(tb.time[k] - t_lo)
            jt_q.append(qv[k])
            if jm.std is not None:
                jt_std[jn] = jm.std
    joints = None
    if info.held_joints:  # constant cubic pieces: the angle, zero rate and acceleration at every time
        from scipy.interpolate import BSpline

        span = np.array([-1.0] * 4 + [grid[-1] - t_lo + 1.0] * 4)
        n_h = len(info.held_joints)
        joints = JointTrajectory(tuple(f"q{k + 1}" for k in range(n_h)),
                                 tuple(BSpline(span, np.full(4, q), 3) for q in info.held_joints), (0.0,) * n_h,
                                 info.joint_cutoff, tuple(grid - t_lo for _ in range(n_h)),
                                 tuple(np.full(n, q) for q in info.held_joints))
        for k, q in enumerate(info.held_joints):
            signals[f"q{k + 1}"] = np.full(n, float(q))
    if jt_names:
        order = np.argsort([int(nm[1:]) for nm in jt_names])
        splines, lams = [], []
        for i in order:
            tt, qq = jt_t[i], jt_q[i]
            if len(tt) < 5:
                raise LogError(f"{where}: joint {jt_names[i]}: fewer than 5 samples in the window")
            lam = 1.0 / (float(np.mean(np.diff(tt))) * (2.0 * math.pi * info.joint_cutoff) ** 4)
            try:
                sp = make_smoothing_spline(tt, qq, lam=lam)
            except (ValueError, np.linalg.LinAlgError) as e:
                raise LogError(f"{where}: joint {jt_names[i]}: the smoothing spline failed ({e})") from None
            splines.append(sp)
            lams.append(lam)
        names = tuple(jt_names[i] for i in order)
        joints = JointTrajectory(names, tuple(splines), tuple(lams), info.joint_cutoff, tuple(jt_t[i] for i in order),
                                 tuple(jt_q[i] for i in order))
        qg = joints(grid - t_lo)[0]
        for k, nm in enumerate(names):
            signals[nm] = qg[:, k]
        std.update(jt_std)
    return Log(name=name, path=where, system=info.system, source=info.source, t=grid - t_lo, t0=t_lo,
               signals=signals, std=std, joints=joints, thrust=thrust, command=command, command_unit=command_unit,
               wrench=wrench, payload=payload, passive=info.passive and not thrust and not command and wrench is None,
               files=tuple(tb.where for tb in tabs), segment=None if seg is None else str(seg))


def _signal_names(sm: StreamMap) -> list[str]:
    out = []
    if sm.position is not None:
        out += ["x", "y", "z"]
    if sm.depth is not None or sm.pressure is not None:
        out += ["z"]
    if sm.quaternion is not None or sm.euler is not None:
        out += ["roll", "pitch", "yaw"]
    if sm.velocity is not None:
        out += ["u", "v", "w"]
    if sm.angular_velocity is not None:
        out += ["p", "q", "r"]
    if sm.wrench is not None:
        out += ["wrench"]
    if sm.thrust:
        out += ["thrust"] + [f"thrust.{n}" for n in sm.thrust]
    if _commands_of(sm):
        out += ["command"] + [f"command.{n}" for n in _commands_of(sm)]
    if sm.payload is not None:
        out += ["payload"]
    out += list(sm.joints or {})
    return out


def load_logs(paths, n_joints: int | None = None, thruster_names: tuple[str, ...] | None = None) -> list[Log]:
    """Every log of ``paths`` (mapping files), all read and checked before any work; names must differ."""
    logs = [load_log(p, n_joints, thruster_names) for p in paths]
    seen: dict[str, str] = {}
    for lg in logs:
        if lg.name in seen:
            raise LogError(f"{lg.path}: trial name {lg.name!r} is also the name of {seen[lg.name]}")
        seen[lg.name] = lg.path
    return logs
