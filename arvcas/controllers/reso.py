"""Reduced-order extended state observer (RESO), paper eq. (14)-(16), docs/model.md §5.

Per DOF of eta (in {n}) the observer estimates ``chi1 = eta_dot`` (``z1``, m/s or rad/s) and the
total disturbance ``chi2 = Mhat^-1 f(eta, nu)`` (``z2 = chi2_hat``, m/s^2 or rad/s^2) of
``chi1' = chi2 + Mhat^-1 tau_eta``, ``chi2' = (Mhat^-1 f)'``.

``reso_step`` is a pure expression over any CasADi type (SX, MX, DM), Python floats and NumPy
arrays, elementwise per DOF. ``reso_gains`` works on numbers and CasADi types alike;
``reso_poles`` and ``check_reso_stability`` are NumPy-only checks on numbers.
"""

from __future__ import annotations

import numpy as np

__all__ = ["reso_gains", "reso_step", "reso_poles", "check_reso_stability"]

_RULES = ("spec", "paper")


def reso_gains(omega, rule="spec"):
    """Observer gains ``(beta1, beta2)`` from the bandwidth ``omega`` (rad/s), per DOF.

    ``rule="spec"``: ``(2 omega, omega^2)``, both continuous poles at ``-omega`` (bandwidth
    parametrisation). ``rule="paper"``: ``(2 omega, omega)`` as printed in eq. (16).
    """
    if rule == "spec":
        return 2 * omega, omega**2  # eq. 16 erratum (docs/model.md §5): beta2 = omega^2 (print: omega)
    if rule == "paper":
        return 2 * omega, omega  # eq. 16 as printed (docs/model.md §5 option beta2_rule = "paper")
    raise ValueError(f"unknown RESO beta2 rule {rule!r}; expected one of {_RULES}")


def reso_step(z1, z2, eta_dot, tau_eta, Mhat_inv, beta1, beta2, h):
    """One RESO sample, eq. (15) by explicit Euler (docs/model.md §5): ``(z1(k+1), z2(k+1))``.

    ``err = eta_dot - z1``; ``z1+ = z1 + h (z2 + Mhat^-1 tau_eta + beta1 err)``;
    ``z2+ = z2 + h beta2 err``.

    Args:
        z1: estimate of ``eta_dot`` at sample k (m/s or rad/s), in {n}.
        z2: estimate of the total disturbance ``chi2`` at sample k (m/s^2 or rad/s^2).
        eta_dot: measured (estimated) ``eta_dot`` at sample k.
        tau_eta: generalised force in {n} (N or N m) held over the interval this step
            integrates; docs/model.md §5 passes the command of the previous sample (the RESO runs before
            the new command exists). The step is exactly eq. (15) by explicit Euler when this is
            the force the plant receives until the next sample; any other choice adds
            ``h Mhat^-1 (tau_applied - tau_eta)`` to the ``z1`` prediction error.
        Mhat_inv: inverse of the diagonal nominal inertia, as its diagonal (1/kg or 1/(kg m^2)),
            applied elementwise.
        beta1, beta2: observer gains (1/s and 1/s^2), see :func:`reso_gains`.
        h: sampling period (s).
    """
    err = eta_dot - z1
    z1_next = z1 + h * (z2 + Mhat_inv * tau_eta + beta1 * err)
    z2_next = z2 + h * beta2 * err
    return z1_next, z2_next


def reso_poles(omega, h, rule="spec"):
    """Poles of the discrete estimation-error dynamics of :func:`reso_step` (numbers only).

    The error ``(chi1 - z1, chi2 - z2)`` evolves, for a constant disturbance, by
    ``[[1 - h beta1, h], [-h beta2, 1]]``, whose eigenvalues are
    ``1 + h (-beta1 +- sqrt(beta1^2 - 4 beta2)) / 2``: a double pole at ``1 - h omega`` for the
    spec rule. Returns a complex array of shape ``omega.shape + (2,)``.
    """
    omega = np.asarray(omega, dtype=float)
    beta1, beta2 = reso_gains(omega, rule)
    root = np.sqrt((beta1**2 - 4 * beta2).astype(complex))
    return np.stack([1 + h * (-beta1 + root) / 2, 1 + h * (-beta1 - root) / 2], axis=-1)


def check_reso_stability(omega, h, rule="spec"):
    """Raise ``ValueError`` unless every DOF's discrete RESO is stable (numbers, not symbolic).

    Spec rule: stable iff ``0 < h omega < 2`` (double pole ``1 - h omega`` inside the unit
    circle; ``omega > 0`` as the paper requires), checked exactly on ``h omega``. Paper rule: the
    spectral radius of the error dynamics (see :func:`reso_poles`) must be below 1.
    """
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    h = float(h)
    if rule == "spec":
        bad = ~((omega > 0) & (h * omega < 2))
    else:
        bad = ~((omega > 0) & (np.abs(reso_poles(omega, h, rule)).max(axis=-1) < 1))
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"RESO unstable ({rule} rule) for DOF {i}: h*omega = {h:g}*{omega[i]:g} = "
            f"{h * omega[i]:g}; the spec rule needs 0 < h*omega < 2 (docs/model.md §5)"
        )
