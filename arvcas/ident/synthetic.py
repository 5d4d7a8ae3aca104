"""Synthetic trials: logs simulated from a system with known parameters and sensor noise, written as real logs.

Two kinds of trial, one writer (:func:`write_trial`):

* **passive** (the default): the thrusters off, the arm moving between poses by rest-to-rest quintics, as
  in the Hinsdale pool trials, seen by a pool's motion capture;
* **driven** (``excitation``, a :class:`PwmExcitation`): each thruster sent a PWM command, as an autopilot
  logs it (ArduSub's ``SERVO_OUTPUT_RAW``): body wrench demands in steps, one actuated degree of freedom
  at a time, allocated to the thrusters (:func:`arvcas.model.thrusters.allocate`) and turned into each
  thruster's command through the inverse of its own map (the T200 table); the plant drives the
  system's thruster dynamics (lag, map) with them. Seen by the vehicle's own sensors (``sensors =
  "vehicle"``): the autopilot's attitude and gyro, and a depth sensor. ``drift`` adds a heave force the
  model lacks (a tether paid out, a buoyancy change), ramping from zero to ``drift`` N over the trial and
  not written to the log: the vehicle's depth drifts, as a real one's does.

The truth is simulated with a fine RK4 step (:data:`TRUTH_STEP_S`), then sampled like the sensors and
written as CSV files with a mapping file (docs/logs.md), so that reading them back runs the whole pipeline
of a real log (alignment, frames, joint splines, thruster commands):

* ``sensors = "mocap"``: ``pose.csv``, motion capture, position (m) and attitude quaternion (x, y, z, w) in
  NED/FRD, 100 Hz; ``imu.csv``, body angular velocity (rad/s), 100 Hz;
* ``sensors = "vehicle"``: ``imu.csv``, attitude as roll, pitch, yaw (rad, NED/FRD) and body angular
  velocity (rad/s), 100 Hz; ``depth.csv``, depth (m), 50 Hz;
* ``joints.csv``: joint angles (rad), 50 Hz (none for a vehicle without an arm);
* ``cmd.csv`` (driven trials): each thruster's command in its map's unit, 50 Hz, held between samples.

The streams' samples fall on the log's 50 Hz time base, so the noise the identification sees is the white
noise written (interpolating between noisy samples would average it); tests/test_logs.py checks alignment.

:data:`NOISE` gives the white noise of each: a motion capture's millimetres and tenths of a degree (the
same tenth of a degree for an autopilot's attitude estimate), a MEMS gyro's noise, an encoder's
resolution, and a pressure depth sensor's: 2 mm, the Bar30's resolution (TE Connectivity MS5837-30BA
data sheet: 0.2 mbar RMS at its finest oversampling, 2 mm of water). They are assumptions stated in
docs/identification.md (the actuated study), not measurements; each mapping file states them as the
signals' ``std``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arvcas.ident import plant as plant_mod
from arvcas.ident.logs import Log
from arvcas.sim.trajectory import rest_to_rest

__all__ = ["NOISE", "TRUTH_STEP_S", "QuinticMoves", "PwmExcitation", "excitation", "truth", "write_trial"]

TRUTH_STEP_S = 0.0025
NOISE = {"position": 0.001, "attitude": math.radians(0.1), "rate": 0.005, "joint": 2e-4,
         "depth": 0.002}  # m, rad, rad/s, rad, m
_POSE_HZ, _IMU_HZ, _JOINT_HZ, _DEPTH_HZ, _CMD_HZ = 100.0, 100.0, 50.0, 50.0, 50.0
SENSORS = ("mocap", "vehicle")
# the largest wrench demand per degree of freedom of a driven trial (N: surge, sway, heave; N m: roll, pitch,
# yaw), sized for a BlueROV2: surge and sway of about 0.2 m/s (their thrust, 8.5 cm below the centre of
# gravity, pitches or rolls it by up to about 30 deg against its metacentric moment), heave of about
# 0.25 m/s, roll of about 10 deg, yaw of about 40 deg/s; each step's demand is a random fraction (0.3 .. 1)
WRENCH_DEMAND = (8.0, 8.0, 20.0, 0.3, 0.3, 2.0)


@dataclass(frozen=True)
class QuinticMoves:
    """Joint angles through ``poses`` (n_moves + 1, n_joints) reached at ``times`` by rest-to-rest quintics."""

    times: np.ndarray
    poses: np.ndarray

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"q{i + 1}" for i in range(self.poses.shape[1]))

    def __call__(self, t):
        t = np.asarray(t, dtype=float)
        q = np.empty(t.shape + (self.poses.shape[1],))
        qd, qdd = np.zeros_like(q), np.zeros_like(q)
        k = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 2)
        t0, t1 = self.times[k], self.times[k + 1]
        T = t1 - t0
        s = np.clip((t - t0) / T, 0.0, 1.0)
        moving = ((t >= t0) & (t <= t1))[..., None]
        a, b = self.poses[k], self.poses[k + 1]
        d = b - a
        b, bd, bdd = rest_to_rest(s)
        q[:] = a + d * b[..., None]
        qd[:] = np.where(moving, d * (bd / T)[..., None], 0.0)
        qdd[:] = np.where(moving, d * (bdd / T**2)[..., None], 0.0)
        return q, qd, qdd


def moves(system, duration: float, seed: int, hold: float = 1.0, move: float = 2.5) -> QuinticMoves:
    """Random poses within the middle half of each joint's range, from and back to the stowed pose."""
    rng = np.random.default_rng(seed)
    P = system.params
    n = system.n_joints
    stow = np.array([P[f"arm.stow.q{i}"] for i in range(1, n + 1)])
    lo = np.array([P[f"arm.joint{i}.qmin"] for i in range(1, n + 1)])
    hi = np.array([P[f"arm.joint{i}.qmax"] for i in range(1, n + 1)])
    mid, half = 0.5 * (lo + hi), 0.25 * (hi - lo)
    times, poses = [0.0, hold], [stow, stow]
    while times[-1] + move + hold < duration - move:
        times.append(times[-1] + move)
        poses.append(mid + half * rng.uniform(-1, 1, n))
        times.append(times[-1] + hold)
        poses.append(poses[-1])
    times.append(times[-1] + move)
    poses.append(stow)
    times.append(max(duration, times[-1]) + 1.0)
    poses.append(stow)
    return QuinticMoves(np.array(times), np.array(poses))


@dataclass(frozen=True)
class PwmExcitation:
    """Thruster commands of a driven trial on a 50 Hz time base: ``C[k]`` (one column per thruster
    of ``names``, in the map's ``unit``) is sent from ``t[k]`` until ``t[k + 1]``; ``demand`` is the body wrench
    each row was allocated from (N, N m), ``dof`` the degree of freedom each row excites (-1 at rest)."""

    t: np.ndarray
    C: np.ndarray
    names: tuple[str, ...]
    unit: str
    demand: np.ndarray
    dof: np.ndarray

    def at(self, t) -> np.ndarray:
        """The commands held at times ``t`` (len(t) x n_thrusters)."""
        k = np.clip(np.searchsorted(self.t, np.asarray(t, dtype=float) + 1e-9, side="right") - 1, 0, len(self.t) - 1)
        return self.C[k]


def excitation(system, duration: float, seed: int, hold: tuple[float, float] = (0.6, 2.0),
               rest: float = 1.0) -> PwmExcitation:
    """Steps of wrench demand in each actuated degree of freedom in turn (equal shares of ``duration`` after
    ``rest`` s at rest): each step holds a random time in ``hold`` (s) with a random fraction 0.3 .. 1 of
    :data:`WRENCH_DEMAND`, its sign alternating (so the vehicle comes back); the demand is allocated to the
    thrusters (the system's own allocation, clipped to each map's range) and each thrust turned into its
    command through the inverse of the thruster's map. Needs a system whose thrusters have command maps."""
    import casadi as ca

    from arvcas.model import thrusters
    from arvcas.system.params import view

    st = system.layout.structure
    if not st.has_thruster_dynamics:
        raise ValueError(f"{system.name}: a driven trial needs thrusters with command maps (thruster dynamics)")
    rng = np.random.default_rng(20_000 + seed)
    P = view(ca.DM(system.params.vector()), system.layout)
    maps = thrusters.thruster_maps(P)
    units = {m.unit for m in maps}
    if len(units) != 1:
        raise ValueError(f"{system.name}: a driven trial needs one command unit for every thruster, got {sorted(units)}")
    t = np.arange(int(round(duration * _CMD_HZ)) + 1) / _CMD_HZ
    tau = np.zeros((len(t), 6))
    dof = np.full(len(t), -1)
    acts = thrusters.actuated(st)
    share = (duration - rest) / len(acts)
    for j, k in enumerate(acts):
        a, sign = rest + j * share, float(rng.choice([-1.0, 1.0]))
        while a < rest + (j + 1) * share - 0.2:
            b = min(a + rng.uniform(*hold), rest + (j + 1) * share)
            sel = (t >= a) & (t < b)
            tau[sel, k] = sign * rng.uniform(0.3, 1.0) * WRENCH_DEMAND[k]
            dof[sel] = k
            a, sign = b, -sign
    levels, back = np.unique(tau, axis=0, return_inverse=True)
    U = np.stack([np.array(thrusters.allocate(P, ca.DM(w))).reshape(-1) for w in levels], axis=1)[:, back.reshape(-1)]
    C = np.empty((len(t), U.shape[0]))
    for i, m in enumerate(maps):
        lo, hi = (float(ca.DM(thrusters.map_thrust(P, m, ca.DM(v)))) for v in thrusters.map_range(P, m))
        u = np.clip(U[i], 0.999 * lo, 0.999 * hi)
        s = np.array(thrusters.map_inverse(P, m, ca.DM(u))).reshape(-1)
        C[:, i] = np.array(ca.DM(thrusters.command_of(P, m, ca.DM(s)))).reshape(-1)
    return PwmExcitation(t=t, C=C, names=tuple(st.thrusters or ()), unit=units.pop(), demand=tau, dof=dof)


def truth(system, duration: float, seed: int, p: np.ndarray | None = None, x0: np.ndarray | None = None,
          rate: float = 400.0, excite: PwmExcitation | None = None,
          drift: float = 0.0) -> tuple[np.ndarray, np.ndarray, QuinticMoves]:
    """(t, X (N x 12), joint motion): the vehicle simulated at ``rate`` samples/s (RK4 at TRUTH_STEP_S),
    passive, or driven by the commands ``excite``; with a heave force (body z, N) ramping from 0 to ``drift``
    over ``duration``."""
    jm = moves(system, duration, seed)
    t = np.arange(int(round(duration * rate)) + 1) / rate
    command, unit = {}, {}
    if excite is not None:
        C = excite.at(t)
        command = {n: C[:, i] for i, n in enumerate(excite.names)}
        unit = {n: excite.unit for n in excite.names}
    wrench = None
    if drift:
        wrench = np.zeros((len(t), 6))
        wrench[:, 2] = drift * t / duration
    lg = Log(name="truth", path="<synthetic>", system=None, source="", t=t, t0=0.0, signals={}, std={},
             joints=jm, thrust={}, command=command, command_unit=unit, wrench=wrench, payload=None,
             passive=excite is None, files=())
    m = max(1, int(math.ceil((1.0 / rate) / TRUTH_STEP_S - 1e-9)))
    pl = plant_mod.LogPlant(system, m=m)
    x0 = np.zeros(12) if x0 is None else x0
    X = plant_mod.simulate(pl, lg, x0, system.params.vector() if p is None else p)
    return t, X, jm


def _quat(e: np.ndarray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) of ZYX Euler angles (N x 3)."""
    cr, sr = np.cos(e[:, 0] / 2), np.sin(e[:, 0] / 2)
    cp, sp = np.cos(e[:, 1] / 2), np.sin(e[:, 1] / 2)
    cy, sy = np.cos(e[:, 2] / 2), np.sin(e[:, 2] / 2)
    return np.stack([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
                     cr * cp * cy + sr * sp * sy], axis=1)


def _csv(path: Path, header: list[str], cols: list[np.ndarray]) -> None:
    np.savetxt(path, np.stack(cols, axis=1), delimiter=",", header=",".join(header), comments="", fmt="%.10g")


def write_trial(directory, name: str, system, duration: float = 20.0, seed: int = 0, p: np.ndarray | None = None,
                noise: dict | None = None, rate: float = 50.0, excite: PwmExcitation | None = None,
                drift: float = 0.0, sensors: str = "mocap") -> Path:
    """Simulate a trial of ``system`` (seed: the arm's poses and the noise) and write it as a log; returns the
    mapping file ``<directory>/<name>.log.toml``. Passive, or driven by the thruster commands ``excite``
    (:func:`excitation`, at least ``duration`` long); ``drift``: the final value (N, body z) of a heave force
    ramping from zero, which the log does not hold; ``sensors``: :data:`SENSORS` (module docstring)."""
    if sensors not in SENSORS:
        raise ValueError(f"sensors: expected one of {', '.join(SENSORS)}, got {sensors!r}")
    if excite is not None and excite.t[-1] < duration + 0.25 - 1e-9:
        raise ValueError(f"excite: {excite.t[-1]:g} s of commands for a trial of {duration:g} s (+0.25 s)")
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    nz = dict(NOISE, **(noise or {}))
    rng = np.random.default_rng(10_000 + seed)
    x0 = np.zeros(12)
    if excite is None:
        x0[3:6] = rng.uniform(-0.15, 0.15, 3)  # released off its rest attitude: it rocks back
    else:
        x0[5] = rng.uniform(-np.pi, np.pi)  # at rest, any heading
    t, X, jm = truth(system, duration + 0.5, seed, p, x0, excite=excite, drift=drift * (duration + 0.5) / duration)

    def at(hz, offset=0.0):
        ts = np.arange(0.0, duration + 0.25, 1.0 / hz) + offset
        return ts, np.stack([np.interp(ts, t, X[:, i]) for i in range(12)], axis=1)

    streams = []
    if sensors == "mocap":
        tp, Xp = at(_POSE_HZ)
        e = Xp[:, 3:6] + rng.normal(0, nz["attitude"], (len(tp), 3))
        pos = Xp[:, 0:3] + rng.normal(0, nz["position"], (len(tp), 3))
        qv = _quat(e)
        _csv(d / f"{name}_pose.csv", ["t", "x", "y", "z", "qx", "qy", "qz", "qw"], [tp, *pos.T, *qv.T])
        streams.append(f"""file = "{name}_pose.csv"
time = "t"
position = {{ columns = ["x", "y", "z"], unit = "m", std = {nz["position"]!r} }}
quaternion = {{ columns = ["qx", "qy", "qz", "qw"], std = {nz["attitude"]!r} }}""")
    ti, Xi = at(_IMU_HZ)
    w = Xi[:, 9:12] + rng.normal(0, nz["rate"], (len(ti), 3))
    gyro = f'angular_velocity = {{ columns = ["wx", "wy", "wz"], unit = "rad/s", std = {nz["rate"]!r} }}'
    if sensors == "mocap":
        _csv(d / f"{name}_imu.csv", ["t", "wx", "wy", "wz"], [ti, *w.T])
        streams.append(f'file = "{name}_imu.csv"\ntime = "t"\n{gyro}')
    else:
        e = Xi[:, 3:6] + rng.normal(0, nz["attitude"], (len(ti), 3))
        e[:, 2] = np.angle(np.exp(1j * e[:, 2]))  # the autopilot's heading, wrapped to (-pi, pi]
        _csv(d / f"{name}_imu.csv", ["t", "roll", "pitch", "yaw", "wx", "wy", "wz"], [ti, *e.T, *w.T])
        streams.append(f"""file = "{name}_imu.csv"
time = "t"
euler = {{ columns = ["roll", "pitch", "yaw"], unit = "rad", std = {nz["attitude"]!r} }}
{gyro}""")
        td, Xd = at(_DEPTH_HZ)
        z = Xd[:, 2] + rng.normal(0, nz["depth"], len(td))
        _csv(d / f"{name}_depth.csv", ["t", "depth"], [td, z])
        streams.append(f'file = "{name}_depth.csv"\ntime = "t"\n'
                       f'depth = {{ columns = ["depth"], unit = "m", std = {nz["depth"]!r} }}')
    if excite is not None:
        tc = np.arange(0.0, duration + 0.25, 1.0 / _CMD_HZ)
        _csv(d / f"{name}_cmd.csv", ["t", *excite.names], [tc, *excite.at(tc).T])
        rows = "\n".join(f'{n} = {{ columns = ["{n}"], unit = "{excite.unit}" }}' for n in excite.names)
        streams.append(f'file = "{name}_cmd.csv"\ntime = "t"\n[stream.command]\n{rows}')
    joints = ""
    if system.n_joints:
        tj = np.arange(0.0, duration + 0.25, 1.0 / _JOINT_HZ)
        qj = jm(tj)[0] + rng.normal(0, nz["joint"], (len(tj), system.n_joints))
        _csv(d / f"{name}_joints.csv", ["t", *jm.names], [tj, *qj.T])
        rows = "\n".join(f'{n} = {{ column = "{n}", std = {nz["joint"]!r} }}' for n in jm.names)
        joints = f"""
[[stream]]
file = "{name}_joints.csv"
time = "t"
[stream.joints]
{rows}
"""
    what = "passive vehicle" if excite is None else "thrusters driven by the commands of cmd.csv"
    what += ", arm moves" if system.n_joints else ""
    what += f"; a heave force the log does not hold, 0 -> {drift:g} N" if drift else ""
    head = "passive = true\n" if excite is None else ""
    body = "".join(f"\n[[stream]]\n{x}\n" for x in streams)
    text = f'''# A synthetic trial of {system.name} (arvcas.ident.synthetic, seed {seed}): {what}.
[log]
name = "{name}"
system = "{system.name}"
source = "arvcas.ident.synthetic.write_trial(seed={seed}, duration={duration!r}{f', drift={drift!r}' if drift else ''})"
{head}rate = {rate!r}
{body}{joints}'''
    path = d / f"{name}.log.toml"
    path.write_text(text, encoding="utf-8")
    return path
