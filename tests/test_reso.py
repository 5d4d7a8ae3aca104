"""RESO (eq. 14-16, docs/model.md §5): discrete poles, disturbance estimation on a double integrator, checks."""

import casadi as ca
import numpy as np
import pytest

from arvcas.controllers.reso import check_reso_stability, reso_gains, reso_poles, reso_step


def _error_matrix(omega, h, rule):
    """d(z1+, z2+)/d(z1, z2) of reso_step built on SX: the estimation-error transition matrix."""
    z = ca.SX.sym("z", 2)
    eta_dot, tau, Minv = ca.SX.sym("eta_dot"), ca.SX.sym("tau"), ca.SX.sym("Minv")
    beta1, beta2 = reso_gains(omega, rule)
    z1n, z2n = reso_step(z[0], z[1], eta_dot, tau, Minv, beta1, beta2, h)
    jac = ca.Function("reso_jac", [z, eta_dot, tau, Minv], [ca.jacobian(ca.vertcat(z1n, z2n), z)])
    return np.array(jac([0.3, -0.1], 0.7, 12.0, 1e-3))


@pytest.mark.parametrize("omega, h", [(0.5, 0.1), (1.0792, 0.1), (4.0, 0.05), (15.0, 0.1)])
def test_spec_rule_double_pole_at_one_minus_h_omega(omega, h):
    A = _error_matrix(omega, h, "spec")
    lam = 1 - h * omega
    # characteristic polynomial (lambda - (1 - h omega))^2: trace and determinant, exactly
    assert abs(np.trace(A) - 2 * lam) <= 1e-12
    assert abs(np.linalg.det(A) - lam**2) <= 1e-12
    # numerical eigenvalues of a defective double pole are accurate to ~sqrt(machine eps)
    assert np.max(np.abs(np.linalg.eigvals(A) - lam)) <= 1e-6
    assert np.allclose(reso_poles(omega, h, "spec"), lam, rtol=0, atol=1e-15)


def test_paper_rule_poles_differ():
    omega, h = 4.0, 0.05
    A = _error_matrix(omega, h, "paper")
    eig = np.sort_complex(np.linalg.eigvals(A).astype(complex))
    assert np.max(np.abs(eig - np.sort_complex(reso_poles(omega, h, "paper")))) <= 1e-12
    # beta2 = omega (as printed) splits the pair: 0.6268 and 0.9732 instead of 0.8, 0.8
    assert np.max(np.abs(eig - (1 - h * omega))) >= 0.15


def test_gains():
    assert reso_gains(3.0) == (6.0, 9.0)
    assert reso_gains(3.0, "paper") == (6.0, 3.0)
    with pytest.raises(ValueError):
        reso_gains(3.0, "other")


def test_stability_check():
    check_reso_stability([1.0, 19.9, 0.5], 0.1)  # h omega = 1.99 passes
    with pytest.raises(ValueError, match="h\\*omega"):
        check_reso_stability([1.0, 20.0], 0.1)  # h omega = 2: pole at -1
    with pytest.raises(ValueError):
        check_reso_stability(25.0, 0.1)
    with pytest.raises(ValueError):
        check_reso_stability(0.0, 0.1)  # pole at +1: no convergence
    # the printed rule has its own boundary (poles 1 + h(-omega +- sqrt(omega^2 - omega)))
    check_reso_stability(10.0, 0.1, rule="paper")
    with pytest.raises(ValueError):
        check_reso_stability(25.0, 0.1, rule="paper")


def _double_integrator(omega, h, tf, a, wd, b, ts, Minv=0.5):
    """x'' = Minv tau + d(t), d = a sin(wd t) + b 1(t >= ts); chi1 = x' measured exactly.

    The plant is integrated exactly under a zero-order hold of tau. At sample k the control
    tau_k = (-chi1_k - z2_k)/Minv uses the current estimate and is held over [t_k, t_{k+1}); the
    observer step uses (eta_dot_k, tau_k), so z_{k+1} is eq. (15) by explicit Euler over that
    interval.
    """
    beta1, beta2 = reso_gains(omega)
    n = round(tf / h)
    t = h * np.arange(n + 1)

    def int_d(t0, t1):
        return a * (np.cos(wd * t0) - np.cos(wd * t1)) / wd + b * max(0.0, t1 - max(t0, ts))

    chi1, z1, z2 = 0.2, 0.0, 0.0
    z2s = np.empty(n + 1)
    for k in range(n):
        z2s[k] = z2
        tau = (-chi1 - z2) / Minv
        z1, z2 = (float(v) for v in reso_step(z1, z2, chi1, tau, Minv, beta1, beta2, h))
        chi1 += h * Minv * tau + int_d(t[k], t[k + 1])
    z2s[n] = z2
    d = a * np.sin(wd * t) + b * (t >= ts)
    return t, z2s, d


def test_estimates_step_disturbance_exactly():
    t, z2, d = _double_integrator(omega=4.0, h=0.05, tf=15.0, a=0.0, wd=1.0, b=1.0, ts=5.0)
    # constant d: the error decays like k (1 - h omega)^k = k 0.8^k; 5 s after the step < 1e-7
    assert np.max(np.abs(z2 - d)[t >= 10.0]) <= 1e-7


def test_estimates_sinusoid_plus_step():
    omega, a, wd = 4.0, 0.3, 0.5
    t, z2, d = _double_integrator(omega=omega, h=0.05, tf=30.0, a=a, wd=wd, b=1.0, ts=5.0)
    e = np.abs(z2 - d)
    # the steady lag of a bandwidth-omega observer is 2 |d'| / omega <= 2 a wd / omega = 0.075
    bound = 2 * a * wd / omega
    assert np.max(e[(t >= 3.0) & (t < 5.0)]) <= 1.07 * bound
    assert np.max(e[t >= 8.0]) <= 1.07 * bound  # 3 s after the unit step
    assert np.max(e[t >= 8.0]) >= 0.5 * bound  # and the lag is real (the test can tell)


def test_symbolic_six_dof_step_matches_numpy():
    names = ("z1", "z2", "eta_dot", "tau", "Minv", "omega")
    z1, z2, eta_dot, tau, Minv, omega = (ca.SX.sym(n, 6) for n in names)
    h = ca.SX.sym("h")
    beta1, beta2 = reso_gains(omega)
    outs = list(reso_step(z1, z2, eta_dot, tau, Minv, beta1, beta2, h))
    f = ca.Function("reso", [z1, z2, eta_dot, tau, Minv, omega, h], outs)
    rng = np.random.default_rng(3)
    a = [rng.normal(size=6) for _ in range(4)] + [rng.uniform(1e-4, 1e-3, 6), rng.uniform(0.5, 2, 6), 0.1]
    sym = [np.array(o).ravel() for o in f(*a)]
    b1, b2 = reso_gains(a[5])  # NumPy arrays in, NumPy arithmetic
    num = reso_step(*a[:5], b1, b2, a[6])
    # by hand: err = eta_dot - z1, z1 + h (z2 + Minv tau + beta1 err), z2 + h beta2 err
    err = a[2] - a[0]
    hand = (a[0] + 0.1 * (a[1] + a[4] * a[3] + 2 * a[5] * err), a[1] + 0.1 * a[5] ** 2 * err)
    for s, n, m in zip(sym, num, hand):
        assert np.max(np.abs(s - m)) <= 1e-14 and np.max(np.abs(np.asarray(n) - m)) <= 1e-14
