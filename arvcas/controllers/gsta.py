"""Generalised super-twisting algorithm (GSTA) and its adaptive gains, paper eq. (18)-(21),
docs/model.md §5 and 5b.

Per DOF, with sliding variable ``s = e_dot + c e`` (m/s or rad/s), the GSTA output is
``v = -k1 phi1(s) - int k2 phi2(s)`` (eq. 21, m/s^2 or rad/s^2); ``w = -int k2 phi2(s)`` is its
integral state. Everything is sampled with the controller period ``h`` and discretised by
explicit Euler (docs/model.md §4), except :func:`gsta_implicit` (docs/model.md §5b).

Every function is a pure expression over any CasADi type (SX, MX, DM) and also accepts Python
floats and NumPy arrays (numbers come back as ``DM``). Vectors are handled elementwise, one DOF
per entry; scalars broadcast. No Python branching on values: branches are ``ca.if_else``.
``sgn(0) = 0`` (``ca.sign``), which makes ``phi1(0) = phi2(0) = 0``.
"""

from __future__ import annotations

import casadi as ca

__all__ = [
    "phi1",
    "phi2",
    "k2_of_k1",
    "k1_next_proposed",
    "k1_next_agsta",
    "k1_next_traditional",
    "gsta_explicit",
    "gsta_implicit",
]


def phi1(s, mu1, mu2):
    """``phi1(s) = mu1 |s|^(1/2) sgn(s) + mu2 s``, eq. (18)."""
    return mu1 * ca.sqrt(ca.fabs(s)) * ca.sign(s) + mu2 * s


def phi2(s, mu1, mu2):
    """``phi2(s) = mu1^2/2 sgn(s) + 3/2 mu1 mu2 |s|^(1/2) sgn(s) + mu2^2 s``, eq. (18) as printed.

    (It equals ``phi1'(s) phi1(s)``.)
    """
    return (
        mu1**2 / 2 * ca.sign(s)
        + 1.5 * mu1 * mu2 * ca.sqrt(ca.fabs(s)) * ca.sign(s)
        + mu2**2 * s
    )


def k2_of_k1(k1, eps, beta):
    """``k2 = 2 eps k1 + beta + 4 eps^2``, eq. (19)."""
    return 2 * eps * k1 + beta + 4 * eps**2


def k1_next_proposed(k1, s, sigma, l, r, k1min, h):
    """Proposed adaptive law, eq. (19), one explicit-Euler sample of length ``h`` (s).

    ``k1_dot = l`` if ``|s| > sigma``; ``-r k1`` if ``|s| <= sigma`` and ``k1 > k1min``; ``0``
    otherwise. Discretised as

    - ``|s| > sigma``:                    ``k1+ = k1 + h l``
    - ``|s| <= sigma``, ``k1 > k1min``:   ``k1+ = max(k1 - h r k1, k1min)``
    - ``|s| <= sigma``, ``k1 <= k1min``:  ``k1+ = k1``

    Why the decrease stops at ``k1min`` instead of undershooting it (the paper is silent): in
    continuous time the decreasing branch is a discontinuous right-hand side that vanishes at
    ``k1 = k1min``, so the solution decays until it reaches ``k1min`` and stays there: it never
    goes below. Plain Euler would instead overshoot by up to ``h r k1min`` on the last step and
    come to rest at an ``h``-dependent value below the tuned ``k1min`` (and below zero once
    ``h r > 1``). Clamping is the sampled continuous solution's stopping rule; it keeps the
    set ``{k1 >= k1min}`` invariant under the decrease, makes the resting gain exactly ``k1min``
    for any ``h``, and still never zigzags (paper, after eq. 19 and Fig. 10): once at ``k1min``
    with ``|s| <= sigma`` the increment is exactly 0. A gain that starts below ``k1min``
    (Table 2 has ``k1(0) < k1min``) is never decreased, only raised while ``|s| > sigma``.

    Args:
        k1: current gain (units such that ``k1 phi1(s)`` is an acceleration, m/s^2 or rad/s^2).
        s: sliding variable at this sample.
        sigma: neighbourhood of zero (units of ``s``), > 0.
        l: growth rate of ``k1`` (gain per second), > 0.
        r: decay rate (1/s), > 0.
        k1min: floor of the decrease.
        h: sampling period (s).
    """
    outside = ca.fabs(s) > sigma
    decreased = ca.fmax(k1 - h * r * k1, k1min)
    inside = ca.if_else(k1 > k1min, decreased, k1)
    return ca.if_else(outside, k1 + h * l, inside)


def k1_next_agsta(k1, s, sigma, l, h):
    """Original AGSTA law (Guerrero et al. 2019, docs/model.md §5): ``k1_dot = l`` if ``|s| > sigma`` else 0.

    Explicit Euler: ``k1+ = k1 + h l`` outside the neighbourhood, ``k1`` inside; never decreases.
    """
    return ca.if_else(ca.fabs(s) > sigma, k1 + h * l, k1)


def k1_next_traditional(k1, s, sigma, l, k1min, h):
    """The "traditional" decreasing law of Fig. 10 (docs/model.md §5), explicit Euler, deliberately unclamped.

    ``k1_dot = l`` if ``|s| > sigma`` or ``k1 <= k1min``, else ``-l``. Sampled, the gain steps
    by ``+-h l`` and so zigzags around ``k1min`` with amplitude ``h l`` once ``|s| <= sigma``: the
    behaviour the proposed law removes.
    """
    up = ca.logic_or(ca.fabs(s) > sigma, k1 <= k1min)
    return ca.if_else(up, k1 + h * l, k1 - h * l)


def gsta_explicit(s, w, k1, k2, mu1, mu2, h):
    """Explicit-Euler GSTA sample, eq. (18)/(21): returns ``(v, w_next)``.

    ``v = -k1 phi1(s) + w`` (the control at this sample; ``w`` is ``-int k2 phi2``), and
    ``w_next = w - h k2 phi2(s)``. Initial ``w = 0``.
    """
    v = -k1 * phi1(s, mu1, mu2) + w
    w_next = w - h * k2 * phi2(s, mu1, mu2)
    return v, w_next


def gsta_implicit(s, w, k1, k2, mu1, mu2, h):
    """Implicit (backward-Euler) GSTA sample in closed form, docs/model.md §5b: returns ``(v, w_next)``.

    Backward Euler on the nominal sliding dynamics ``s_dot = v``::

        s~ = s + h v,   v = -k1 phi1(s~) + w_next,   w_next = w - h k2 phi2(s~),

    with ``sgn(0)`` set-valued (``[-1, 1]``). Eliminating ``v`` and ``w_next``:
    ``s~ + h k1 phi1(s~) + h^2 k2 phi2(s~) = z := s + h w``. Writing ``s~ = sgn(s~) rho^2``
    (``rho >= 0``), the left side is ``sgn(s~) (a rho^2 + b rho + h^2 k2 mu1^2/2)`` with
    ``a = 1 + h k1 mu2 + h^2 k2 mu2^2`` and ``b = h k1 mu1 + 3/2 h^2 k2 mu1 mu2``, so:

    - ``|z| <= h^2 k2 mu1^2/2``: only ``s~ = 0`` solves it (with ``sgn(0) = z/(h^2 k2 mu1^2/2)``),
      hence ``v = w_next = -s/h``;
    - otherwise ``sgn(s~) = sgn(z)`` and ``rho`` is the positive root of
      ``a rho^2 + b rho + c0 = 0``, ``c0 = h^2 k2 mu1^2/2 - |z| < 0``; then
      ``w_next = w - h k2 phi2(s~)``, ``v = -k1 phi1(s~) + w_next``.

    The root is evaluated as ``rho = -2 c0 / (b + sqrt(b^2 - 4 a c0))``, algebraically equal to
    docs/model.md §5b ``(-b + sqrt(b^2 - 4 a c0)) / (2 a)`` but free of cancellation when ``|c0| << b^2``.
    The branch not taken is kept finite (no NaN/inf in either branch of the graph). Gains are
    those of the current sample; the adaptive laws keep their explicit update (docs/model.md §5b).
    Requires ``h > 0``, ``k1, k2, mu1, mu2 >= 0``.
    """
    z = s + h * w
    abs_z = ca.fabs(z)
    dead_zone = abs_z <= h**2 * k2 * mu1**2 / 2
    a = 1 + h * k1 * mu2 + h**2 * k2 * mu2**2
    b = h * k1 * mu1 + 1.5 * h**2 * k2 * mu1 * mu2
    c0 = ca.fmin(h**2 * k2 * mu1**2 / 2 - abs_z, 0)  # clamped: >= 0 only in the dead zone
    den = b + ca.sqrt(b**2 - 4 * a * c0)  # = 0 only if b = c0 = 0, i.e. z = 0 (dead zone)
    rho = -2 * c0 / ca.if_else(den > 0, den, 1)
    s_tilde = ca.sign(z) * rho**2
    w_off = w - h * k2 * phi2(s_tilde, mu1, mu2)
    v_off = -k1 * phi1(s_tilde, mu1, mu2) + w_off
    v_dead = -s / h
    return ca.if_else(dead_zone, v_dead, v_off), ca.if_else(dead_zone, v_dead, w_off)
