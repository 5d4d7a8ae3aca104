"""Synthetic trials: logs simulated from a system with known parameters and sensor noise, written as real logs.

A passive vehicle (zero thrust) whose arm moves between poses by rest-to-rest quintics, as in the
Hinsdale pool trials; the truth is simulated with a fine RK4 step (:data:`TRUTH_STEP_S`), then sampled
like the sensors of a pool vehicle and written as CSV files with a mapping file (docs/logs.md), so that
reading them back runs the whole pipeline of a real log (alignment, frames, joint splines):

* ``pose.csv``: motion capture, position (m) and attitude quaternion (x, y, z, w) in NED/FRD, 100 Hz;
* ``imu.csv``: body angular velocity (rad/s), 100 Hz;
* ``joints.csv``: joint angles (rad), 50 Hz (none for a vehicle without an arm).

The streams' samples fall on the log's 50 Hz time base, so the noise the identification sees is the white
noise written (interpolating between noisy samples would average it); tests/test_logs.py checks alignment.

:data:`NOISE` gives the white noise of each (a mocap system's millimetres and tenths of a degree, a MEMS
gyro's noise, an encoder's resolution); each mapping file states it as the signal's ``std``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arvcas.ident import plant as plant_mod
from arvcas.ident.logs import Log
from arvcas.sim.trajectory import rest_to_rest

__all__ = ["NOISE", "TRUTH_STEP_S", "QuinticMoves", "truth", "write_trial"]

TRUTH_STEP_S = 0.0025
NOISE = {"position": 0.001, "attitude": math.radians(0.1), "rate": 0.005, "joint": 2e-4}  # m, rad, rad/s, rad
_POSE_HZ, _IMU_HZ, _JOINT_HZ = 100.0, 100.0, 50.0


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


def truth(system, duration: float, seed: int, p: np.ndarray | None = None, x0: np.ndarray | None = None,
          rate: float = 400.0) -> tuple[np.ndarray, np.ndarray, QuinticMoves]:
    """(t, X (N x 12), joint motion): the passive vehicle simulated at ``rate`` samples/s (RK4 at TRUTH_STEP_S)."""
    jm = moves(system, duration, seed)
    t = np.arange(int(round(duration * rate)) + 1) / rate
    lg = Log(name="truth", path="<synthetic>", system=None, source="", t=t, t0=0.0, signals={}, std={},
             joints=jm, thrust={}, command={}, command_unit={}, wrench=None, payload=None, passive=True, files=())
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
                noise: dict | None = None, rate: float = 50.0) -> Path:
    """Simulate a passive trial of ``system`` (seed: the arm's poses and the noise) and write it as a log;
    returns the mapping file ``<directory>/<name>.log.toml``."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    nz = dict(NOISE, **(noise or {}))
    rng = np.random.default_rng(10_000 + seed)
    x0 = np.zeros(12)
    x0[3:6] = rng.uniform(-0.15, 0.15, 3)  # released off its rest attitude: it rocks back
    t, X, jm = truth(system, duration + 0.5, seed, p, x0)

    def at(hz, offset=0.0):
        ts = np.arange(0.0, duration + 0.25, 1.0 / hz) + offset
        return ts, np.stack([np.interp(ts, t, X[:, i]) for i in range(12)], axis=1)

    tp, Xp = at(_POSE_HZ)
    e = Xp[:, 3:6] + rng.normal(0, nz["attitude"], (len(tp), 3))
    pos = Xp[:, 0:3] + rng.normal(0, nz["position"], (len(tp), 3))
    qv = _quat(e)
    _csv(d / f"{name}_pose.csv", ["t", "x", "y", "z", "qx", "qy", "qz", "qw"], [tp, *pos.T, *qv.T])
    ti, Xi = at(_IMU_HZ)
    w = Xi[:, 9:12] + rng.normal(0, nz["rate"], (len(ti), 3))
    _csv(d / f"{name}_imu.csv", ["t", "wx", "wy", "wz"], [ti, *w.T])
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
    text = f'''# A synthetic trial of {system.name} (arvcas.ident.synthetic, seed {seed}): passive vehicle, arm moves.
[log]
name = "{name}"
system = "{system.name}"
source = "arvcas.ident.synthetic.write_trial(seed={seed}, duration={duration!r})"
passive = true
rate = {rate!r}

[[stream]]
file = "{name}_pose.csv"
time = "t"
position = {{ columns = ["x", "y", "z"], unit = "m", std = {nz["position"]!r} }}
quaternion = {{ columns = ["qx", "qy", "qz", "qw"], std = {nz["attitude"]!r} }}

[[stream]]
file = "{name}_imu.csv"
time = "t"
angular_velocity = {{ columns = ["wx", "wy", "wz"], unit = "rad/s", std = {nz["rate"]!r} }}
{joints}'''
    path = d / f"{name}.log.toml"
    path.write_text(text, encoding="utf-8")
    return path
