"""Attitude in logs: rotation matrices from quaternions and ZYX Euler angles and back, and an attitude stream turned
into unwrapped Euler angles a block of rows at a time (:func:`arvcas.ident.logs.load_log`: what a long log costs is
its angles, not n 3 x 3 matrices and their temporaries).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["R_from_quaternion", "R_from_euler", "euler_from_R", "BLOCK_ROWS"]


def R_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) in x, y, z, w order."""
    x, y, z, w = (q[..., i] for i in range(4))
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def R_from_euler(e: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) for (..., 3) angles roll, pitch, yaw (rad): body to world (Fossen)."""
    cr, sr = np.cos(e[..., 0]), np.sin(e[..., 0])
    cp, sp = np.cos(e[..., 1]), np.sin(e[..., 1])
    cy, sy = np.cos(e[..., 2]), np.sin(e[..., 2])
    return np.stack([
        np.stack([cy * cp, -sy * cr + cy * sp * sr, sy * sr + cy * cr * sp], -1),
        np.stack([sy * cp, cy * cr + sr * sp * sy, -cy * sr + sp * sy * cr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1),
    ], -2)


def euler_from_R(R: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (..., 3) roll, pitch, yaw (rad) of rotation matrices (..., 3, 3), unwrapped along axis 0."""
    e = _angles(R)
    return np.unwrap(e, axis=0) if e.ndim == 2 else e


def _angles(R: np.ndarray) -> np.ndarray:
    """:func:`euler_from_R` before the unwrapping: each in (-pi, pi]."""
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    pitch = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], -1)


BLOCK_ROWS = 1 << 14  # rows of an attitude stream (its matrices, its angles), or of the time base, computed at a time


def _slices(n: int, block: int):
    return (slice(i, min(n, i + block)) for i in range(0, n, block))


def _attitude(rows, n: int, f, Cw: np.ndarray, Cb: np.ndarray, point=None,
              block: int = BLOCK_ROWS) -> tuple[list[np.ndarray], np.ndarray | None]:
    """The ZYX Euler angles roll, pitch, yaw (three arrays (n,)), unwrapped, of the rotations
    ``Cw @ f(rows(s)) @ Cb`` (``rows(s)``: the rotation's parameters of the rows ``s``, a slice) and, given
    ``point`` (3,), ``R @ point`` (n, 3), computed a block of rows at a time: what it costs is the angles,
    not n matrices and a dozen temporaries of every row. To the bit :func:`euler_from_R` of the matrices
    of every row at once (each row's matrix and angles are computed alone; the unwrapping carries its
    running sum from block to block, :func:`_unwrap`). Three arrays, not one: each can go once used."""
    e = [np.empty(n) for _ in range(3)]
    arm = None if point is None else np.empty((n, 3))
    for s in _slices(n, block):
        R = Cw @ f(rows(s)) @ Cb
        for k, a in enumerate(_angles(R).T):
            e[k][s] = a
        if arm is not None:
            arm[s] = np.einsum("nij,j->ni", R, point)
    for a in e:
        _unwrap(a, block)
    return e, arm


def _unwrap(p: np.ndarray, block: int = BLOCK_ROWS) -> np.ndarray:
    """``np.unwrap(p, axis=0)`` (period 2 pi) in place, a block of rows at a time: NumPy's steps (its phase
    corrections, then their running sum, which is sequential) with the last row and the sum carried over."""
    period = 2.0 * math.pi
    high, low = period / 2, -period / 2
    last, carry = p[0].copy(), None
    for s in _slices(p.shape[0] - 1, block):
        blk = p[s.start + 1:s.stop + 1]
        dd = np.empty_like(blk)
        dd[0] = blk[0] - last
        np.subtract(blk[1:], blk[:-1], out=dd[1:])
        ddmod = np.mod(dd - low, period) + low
        np.copyto(ddmod, high, where=(ddmod == low) & (dd > 0))
        ph = ddmod - dd
        np.copyto(ph, 0, where=abs(dd) < high)
        if carry is not None:
            ph[0] += carry
        np.cumsum(ph, axis=0, out=ph)
        last, carry = blk[-1].copy(), ph[-1].copy()
        blk += ph
    return p
