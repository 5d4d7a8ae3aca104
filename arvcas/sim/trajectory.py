"""Vehicle trajectories as data (docs/tasks.md): piecewise quintic polynomials in time, per DOF of eta.

A trajectory is a list of segments ``[t_k, t_{k+1}]`` between poses ``eta_k`` (x, y, z in m; phi,
theta, psi in rad, in {n}); on each segment every DOF is the quintic that meets the pose, the rate
``eta_dot`` and the acceleration at both ends. Two segment shapes:

* ``minimum_jerk``: rest to rest (zero rate and acceleration at every waypoint), Flash & Hogan's
  (1985) minimum-jerk polynomial ``eta_k + (eta_{k+1} - eta_k) (10 s^3 - 15 s^4 + 6 s^5)``,
  ``s = (t - t_k) / T``: the vehicle stops at each waypoint;
* ``quintic``: through the waypoints with a rate at each (given, or by default zero at the first and
  last and the central difference ``(eta_{k+1} - eta_{k-1}) / (t_{k+1} - t_{k-1})`` at the inner
  ones) and zero acceleration.

Before the first time the trajectory holds the first pose, after the last the last pose. Two patterns
expand to waypoints: a lawnmower (parallel legs joined by short steps) and approach then hold.

Pure NumPy: the closed loop reads the trajectory sampled at its sample times from the run's time table
(:func:`arvcas.sim.schedule.table`), so a new trajectory changes an input, never the compiled run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Trajectory", "rest_to_rest", "min_jerk", "quintic_coefficients", "from_waypoints", "lawnmower", "approach",
           "SEGMENTS"]

SEGMENTS = ("minimum_jerk", "quintic")


def rest_to_rest(s):
    """The rest-to-rest quintic (Flash & Hogan's minimum-jerk blend) at the normalised time ``s`` in [0, 1]:
    ``(10 s^3 - 15 s^4 + 6 s^5, its first derivative in s, its second)``, from 0 to 1 with zero rate and
    acceleration at both ends. Plain arithmetic on what it is given (a float, a NumPy array), so every
    user computes the same bits; the compiled scenario's arm motion evaluates the same polynomial in
    CasADi (:func:`arvcas.sim.profiles.quintic`)."""
    return (10 * s**3 - 15 * s**4 + 6 * s**5, 30 * s**2 - 60 * s**3 + 30 * s**4, 60 * s - 180 * s**2 + 120 * s**3)


def min_jerk(p0, p1, t0: float, t1: float, t):
    """Flash & Hogan's minimum-jerk move from ``p0`` at ``t0`` to ``p1`` at ``t1`` (rest to rest), closed
    form; ``(p, p_dot, p_ddot)`` at the times ``t`` (held outside ``[t0, t1]``). Rows: times; columns: DOF."""
    p0, p1 = np.atleast_1d(np.asarray(p0, float)), np.atleast_1d(np.asarray(p1, float))
    T = t1 - t0
    s = np.clip((np.asarray(t, float) - t0) / T, 0.0, 1.0)[:, None]
    d = p1 - p0
    b, bd, bdd = rest_to_rest(s)
    return p0 + d * b, d * bd / T, d * bdd / T**2


def quintic_coefficients(T: float, p0, v0, a0, p1, v1, a1) -> np.ndarray:
    """Coefficients ``c_0..c_5`` (rows) of ``p(tau) = sum c_i tau^i`` on ``tau in [0, T]`` meeting position,
    rate and acceleration at both ends (per DOF: columns), the textbook closed form."""
    p0, v0, a0, p1, v1, a1 = (np.asarray(x, float) for x in (p0, v0, a0, p1, v1, a1))
    d = p1 - p0
    c3 = (20 * d - (8 * v1 + 12 * v0) * T - (3 * a0 - a1) * T**2) / (2 * T**3)
    c4 = (-30 * d + (14 * v1 + 16 * v0) * T + (3 * a0 - 2 * a1) * T**2) / (2 * T**4)
    c5 = (12 * d - 6 * (v1 + v0) * T + (a1 - a0) * T**2) / (2 * T**5)
    return np.array([p0, v0, a0 / 2, c3, c4, c5])


@dataclass(frozen=True)
class Trajectory:
    """Segments between ``times`` (strictly increasing, s) with quintic ``coeffs`` (n_seg, 6, 6 DOF) in the
    time since each segment's start; ``points``: the waypoints (n, 6)."""

    times: np.ndarray
    points: np.ndarray
    coeffs: np.ndarray

    def sample(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(eta_d, eta_d_dot, eta_d_ddot)`` at the times ``t`` (arrays (n, 6)); held before and after."""
        t = np.asarray(t, float).ravel()
        ts = self.times
        k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 2)
        tau = np.clip(t - ts[k], 0.0, ts[k + 1] - ts[k])[:, None]
        c = self.coeffs[k]  # (n, 6 powers, 6 DOF)
        p = sum(c[:, i] * tau**i for i in range(6))
        v = sum(i * c[:, i] * tau ** (i - 1) for i in range(1, 6))
        a = sum(i * (i - 1) * c[:, i] * tau ** (i - 2) for i in range(2, 6))
        outside = ((t < ts[0]) | (t > ts[-1]))[:, None]
        return p, np.where(outside, 0.0, v), np.where(outside, 0.0, a)


def default_rates(times, points) -> np.ndarray:
    """The waypoints' rates of a ``quintic`` trajectory when none are given: zero at the first and the last,
    the central difference of the neighbours at the inner ones."""
    t, P = np.asarray(times, float), np.asarray(points, float)
    R = np.zeros_like(P)
    R[1:-1] = (P[2:] - P[:-2]) / (t[2:] - t[:-2])[:, None]
    return R


def from_waypoints(times, points, segment: str = "minimum_jerk", rates=None) -> Trajectory:
    """The trajectory through ``points`` (n x 6) at ``times`` (n, strictly increasing): ``segment`` as the
    module docstring; ``rates`` (n x 6, ``quintic`` only; None: :func:`default_rates`)."""
    t, P = np.asarray(times, float), np.asarray(points, float)
    if segment not in SEGMENTS:
        raise ValueError(f"segment: {segment!r} is not one of {', '.join(SEGMENTS)}")
    if t.ndim != 1 or P.shape != (t.size, 6) or t.size < 2:
        raise ValueError(f"from_waypoints: {t.size} times and points of shape {P.shape} (need n >= 2 and n x 6)")
    if not np.all(np.diff(t) > 0):
        raise ValueError("from_waypoints: times must increase strictly")
    if segment == "minimum_jerk":
        R = np.zeros_like(P)
    else:
        R = default_rates(t, P) if rates is None else np.asarray(rates, float)
    z = np.zeros(6)
    C = np.array([quintic_coefficients(t[k + 1] - t[k], P[k], R[k], z, P[k + 1], R[k + 1], z)
                  for k in range(t.size - 1)])
    return Trajectory(t, P, C)


def lawnmower(start, t0: float, legs: int, leg_length: float, spacing: float, speed: float,
              heading: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A lawnmower's waypoints and times from ``start`` (a pose, 6): ``legs`` parallel legs of ``leg_length``
    (m) along ``heading`` (rad from north in the horizontal plane; default the start's yaw), each next leg
    ``spacing`` (m) to starboard of that heading and run the other way; every move at the mean speed
    ``speed`` (m/s), from ``t0``. Depth and attitude stay the start's. Returns ``(times, points)``."""
    s = np.asarray(start, float)
    psi = s[5] if heading is None else heading
    along = np.array([math.cos(psi), math.sin(psi), 0.0])
    side = np.array([-math.sin(psi), math.cos(psi), 0.0])  # starboard of the heading in NED
    pts, pos = [s[:3].copy()], s[:3].copy()
    for j in range(legs):
        pos = pos + (along if j % 2 == 0 else -along) * leg_length
        pts.append(pos)
        if j < legs - 1:
            pos = pos + side * spacing
            pts.append(pos)
    P = np.array([np.concatenate([p, s[3:]]) for p in pts])
    dist = np.linalg.norm(np.diff(P[:, :3], axis=0), axis=1)
    return t0 + np.concatenate([[0.0], np.cumsum(dist / speed)]), P


def approach(start, target, t0: float, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Approach then hold: from ``start`` at ``t0`` to ``target`` at ``t0 + duration``, held after."""
    return np.array([t0, t0 + duration]), np.array([np.asarray(start, float), np.asarray(target, float)])
