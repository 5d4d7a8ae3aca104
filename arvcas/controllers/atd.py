"""Adaptive tracking differentiator (ATD), paper eq. (12)-(13), docs/model.md §5.

Han's time-optimal synthesis function ``fhan`` drives a discrete double integrator ``(y1, y2)``
towards the input ``x``: ``y1`` is the smoothed reference (m or rad, per DOF of eta in {n}) and
``y2`` its derivative (m/s or rad/s).

Every function is a pure expression over any CasADi type (SX, MX, DM) and also accepts Python
floats and NumPy arrays (numbers come back as ``DM``). Vectors are handled elementwise, one DOF
per entry; scalars broadcast. There is no Python branching on the values.
"""

from __future__ import annotations

import casadi as ca

__all__ = ["fhan", "atd_params", "atd_step"]


def fhan(x1, x2, r0, h0):
    """Han's optimal synthetic rapid control function, exactly eq. (13).

    Args:
        x1: position error ``y1 - x`` (m or rad).
        x2: velocity ``y2`` (m/s or rad/s).
        r0: fast coefficient, the acceleration bound (m/s^2 or rad/s^2), > 0.
        h0: filter coefficient (s), > 0.

    Returns:
        The acceleration command, ``|fhan| <= r0``: linear (``-r0 b2/a0``) near the switching
        curve, ``-r0 sgn(b2)`` away from it.
    """
    a0 = r0 * h0**2
    a1 = h0 * x2
    a2 = x1 + a1
    a3 = ca.sqrt(a0 * (a0 + 8 * ca.fabs(a2)))
    b0 = a1 + ca.sign(a2) * (a3 - a0) / 2
    b1 = (ca.sign(a2 + a0) - ca.sign(a2 - a0)) / 2
    b2 = (a1 + a2 - b0) * b1 + b0
    b3 = (ca.sign(b2 + a0) - ca.sign(b2 - a0)) / 2
    return -r0 * (b2 / a0 - ca.sign(b2)) * b3 - r0 * ca.sign(b2)


def atd_params(A, T, h, A_min):
    """ATD coefficients ``(r0, h0)`` for a step of amplitude ``A`` reached in time ``T``.

    ``r0 = 4 A / T^2`` is the acceleration of the time-optimal bang-bang move over ``A`` in ``T``
    (accelerate for ``T/2``, brake for ``T/2``); ``h0 = 4 h`` is the noise-free filter coefficient.
    Per DOF ``A`` is replaced by ``max(|A|, A_min)`` (docs/model.md §5: ``A = max(|eta_d - eta_hat(0)|,
    A_min)``), so a zero step still gives ``r0 > 0`` and ``fhan`` never divides by zero.

    Args:
        A: step amplitude per DOF, e.g. ``eta_d - eta_hat(0)`` (m or rad); its sign is ignored.
        T: desired transient time (s), default 5 s (docs/model.md §5).
        h: controller sampling period (s).
        A_min: lower bound of the amplitude (m or rad), > 0.

    Returns:
        ``(r0, h0)``: fast coefficient (m/s^2 or rad/s^2) and filter coefficient (s).
    """
    A_eff = ca.fmax(ca.fabs(A), A_min)
    r0 = 4 * A_eff / T**2  # eq. 12 erratum (docs/model.md §5): r0 = 4A/T^2, the print's A/4T^2 is a slip
    h0 = 4 * h  # eq. 12, noise-free branch (the reference eta_d is noise-free, docs/model.md §5)
    return r0, h0


def atd_step(y1, y2, x, r0, h0, h):
    """One ATD sample, eq. (12): ``(y1(k+1), y2(k+1))`` from ``(y1(k), y2(k))`` and input ``x(k)``.

    ``y1+ = y1 + h y2``, ``y2+ = y2 + h fhan(y1 - x, y2, r0, h0)``. The state advances with the
    sampling period ``h``; ``h0`` only shapes ``fhan`` (docs/model.md §5). Initial state per docs/model.md §5:
    ``y1(0) = eta_hat(0)``, ``y2(0) = 0``, input ``x(k) = eta_d``.
    """
    y1_next = y1 + h * y2
    y2_next = y2 + h * fhan(y1 - x, y2, r0, h0)
    return y1_next, y2_next
