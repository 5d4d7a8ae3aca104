"""Link fluid loads (docs/model.md §3): the Gauss-Legendre rule, the drag integral and its convergence, and the
sign of the drag's power.

Measured (recorded here so a change shows): over 30 random moving states (nu, qd != 0), the drag part
of arm_wrench at n_quad points, against n_quad = 64, relative to the drag wrench's norm:
max 1.9e-1 (n=1), 9.8e-3 (2), 1.4e-3 (3), 3.8e-5 (5), 4.1e-7 (8); medians 2.7e-2, 2.9e-5, 6.9e-7,
3.0e-10, 2.0e-14. For generic states v_n(x) never vanishes on a link and the integrand is analytic,
so convergence is exponential; where v_n crosses zero on a link, |v_n| v_n has a jump in its second
derivative and convergence is algebraic, measured O(n^-3) (test_drag_convergence_at_zero_crossing).
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import quad_vec

from arvcas.model import hydro, manipulator
from arvcas.system import params as ap

N_LIST = (1, 2, 3, 5, 8)
N_FINE = 64


# --- the quadrature rule -------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8, 16, 64])
def test_gauss_legendre_rule(n):
    x, w = (np.array(a) for a in hydro.gauss_legendre(n))
    assert x.shape == w.shape == (n,)
    assert np.all((x > 0) & (x < 1)) and np.all(w > 0)
    assert w.sum() == pytest.approx(1.0, abs=1e-14)  # length of [0, 1]
    np.testing.assert_allclose(x + x[::-1], 1.0, atol=1e-14)  # symmetric about 1/2
    for k in range(2 * n):  # exact for every degree <= 2n - 1
        assert w @ x**k == pytest.approx(1.0 / (k + 1), rel=1e-13, abs=1e-15), k
    # ... and not for degree 2n: on [0, 1] the error of x^(2n) is (n!)^4 / ((2n+1) ((2n)!)^2) > 0
    err = 1.0 / (2 * n + 1) - w @ x ** (2 * n)
    expected = math.factorial(n) ** 4 / ((2 * n + 1) * math.factorial(2 * n) ** 2)
    if expected > 1e-11:  # beyond n = 8 the error is below double precision
        assert err == pytest.approx(expected, rel=1e-4)


def test_gauss_legendre_rejects_bad_n():
    for bad in (0, -1, 2.0, True):
        with pytest.raises(ValueError, match="n_quad"):
            hydro.gauss_legendre(bad)


def test_shipped_rules_are_numpys_leggauss():
    """The table (arvcas/data/gauss_legendre.toml) against the installed NumPy's leggauss: the same rules to a
    few units in the last place (the bits may differ with the release, which is why it is a table), for every n."""
    for n in range(1, hydro.MAX_NODES + 1):
        x, w = hydro.leggauss(n)
        X, W = np.polynomial.legendre.leggauss(n)
        np.testing.assert_allclose(x, X, rtol=0, atol=1e-15, err_msg=f"n = {n}")
        np.testing.assert_allclose(w, W, rtol=1e-13, atol=0, err_msg=f"n = {n}")
        assert not x.flags.writeable and not w.flags.writeable


# --- the drag integral on one link ---------------------------------------------------------------


def _drag_reference(rho, Cd, D, s, v, w):
    """f = -1/2 rho Cd D int_0^L |v_n| v_n dx and its moment about the origin, by adaptive quadrature."""
    L = np.linalg.norm(s)
    u = s / L

    def integrand(x):
        vx = v + np.cross(w, x * u)
        vn = vx - (vx @ u) * u
        q = np.linalg.norm(vn) * vn
        return np.concatenate([q, np.cross(x * u, q)])

    val, _ = quad_vec(integrand, 0.0, L, epsabs=1e-14, epsrel=1e-13, limit=500)
    k = -0.5 * rho * Cd * D
    return k * val[:3], k * val[3:]


def test_link_drag_against_adaptive_quadrature():
    rng = np.random.default_rng(50)
    for _ in range(20):
        s = rng.normal(size=3) * 0.4
        v, w = rng.normal(size=3), rng.normal(size=3)
        f_ref, n_ref = _drag_reference(1027.77, 1.0, 0.12, s, v, w)
        f, n = hydro.link_drag(1027.77, 1.0, 0.12, ca.DM(s), ca.DM(v), ca.DM(w), N_FINE)
        got = np.concatenate([np.array(f).ravel(), np.array(n).ravel()])
        ref = np.concatenate([f_ref, n_ref])
        assert np.linalg.norm(got - ref) <= 1e-11 * np.linalg.norm(ref)  # measured 1.1e-15
        # drag is normal to the link axis and linear in rho, Cd and D
        assert abs(np.array(f).ravel() @ s) <= 1e-12 * np.linalg.norm(f_ref) * np.linalg.norm(s)


def test_drag_convergence_at_zero_crossing():
    """v_n(x) = (x - x0) (w x u) crosses zero at x0 = 0.37 L: closed form
    int_0^L |x - x0| (x - x0) dx = ((L - x0)^3 - x0^3) / 3; Gauss-Legendre converges algebraically."""
    L, x0 = 0.6, 0.37 * 0.6
    u = np.array([1.0, 0.0, 0.0])
    w = np.array([0.0, 0.0, 0.7])
    v = -np.cross(w, x0 * u)
    b = np.cross(w, u)
    k = -0.5 * 1000.0 * 1.0 * 0.1
    exact = k * np.linalg.norm(b) * b * ((L - x0) ** 3 - x0**3) / 3.0
    ns = np.array([4, 8, 16, 32, 64, 128])
    errs = []
    for n in ns:
        f, _ = hydro.link_drag(1000.0, 1.0, 0.1, ca.DM(L * u), ca.DM(v), ca.DM(w), int(n))
        errs.append(np.linalg.norm(np.array(f).ravel() - exact) / np.linalg.norm(exact))
    errs = np.array(errs)
    rate = -np.polyfit(np.log(ns), np.log(errs), 1)[0]
    print(f"zero-crossing link: errors {errs}, fitted order {rate:.2f}")
    assert 2.5 < rate < 3.5  # measured 2.96
    assert errs[-1] > 1e-8  # algebraic, not exponential: 128 points still leave ~8e-7


# --- drag in the arm wrench ----------------------------------------------------------------------


def _arm_wrench_fn(n_quad, np_):
    s = [ca.SX.sym(k, 6) for k in ("eta", "nu", "nud", "q", "qd", "qdd")]
    pl, p = ca.SX.sym("payload"), ca.SX.sym("p", np_)
    return ca.Function(f"arm_wrench_nq{n_quad}", [*s, pl, p],
                       [manipulator.arm_wrench(ap.view(p), *s, pl, n_quad)])


@pytest.fixture(scope="module")
def arm_wrench_n(params):
    return {n: _arm_wrench_fn(n, len(params)) for n in (*N_LIST, N_FINE)}


def _moving_states(params, rng, n):
    qmin = np.array([params[f"arm.joint{i}.qmin"] for i in range(1, 7)])
    qmax = np.array([params[f"arm.joint{i}.qmax"] for i in range(1, 7)])
    for _ in range(n):
        eta = np.concatenate([rng.normal(size=3), rng.uniform(-1, 1, 3)])
        nu = rng.normal(size=6) * np.array([0.3, 0.3, 0.3, 0.2, 0.2, 0.2])
        yield eta, nu, rng.uniform(qmin, qmax), rng.normal(size=6) * 0.5


def test_drag_convergence_in_arm_wrench(params, arm_wrench_n):
    p = params.vector()
    p_nodrag = params.replace({"env.Cd": 0.0}).vector()
    z = np.zeros(6)
    errs = {n: [] for n in N_LIST}
    for eta, nu, q, qd in _moving_states(params, np.random.default_rng(0), 30):
        ref = np.array(arm_wrench_n[N_FINE](eta, nu, z, q, qd, z, 0, p)).ravel()
        drag = ref - np.array(arm_wrench_n[N_FINE](eta, nu, z, q, qd, z, 0, p_nodrag)).ravel()
        assert np.linalg.norm(drag) > 1.0  # the states do move the arm through the water
        for n in N_LIST:
            got = np.array(arm_wrench_n[n](eta, nu, z, q, qd, z, 0, p)).ravel()
            errs[n].append(np.linalg.norm(got - ref) / np.linalg.norm(drag))
    worst = np.array([max(errs[n]) for n in N_LIST])
    median = np.array([np.median(errs[n]) for n in N_LIST])
    print("n_quad", N_LIST, "max rel err", worst, "median", median)
    assert np.all(np.diff(worst) < 0) and np.all(np.diff(median) < 0)
    assert worst[N_LIST.index(1)] > 1e-2  # one point is a poor rule: the test can tell rules apart
    assert worst[N_LIST.index(5)] < 1e-4  # default rule: measured 3.8e-5
    assert worst[N_LIST.index(8)] < 2e-6  # measured 4.1e-7


def test_default_plant_uses_five_points(plant, params, arm_wrench_n):
    p = params.vector()
    z = np.zeros(6)
    for eta, nu, q, qd in _moving_states(params, np.random.default_rng(1), 3):
        a = np.array(plant["arm_wrench"](eta, nu, z, q, qd, z, 1, p)).ravel()
        b = np.array(arm_wrench_n[5](eta, nu, z, q, qd, z, 1, p)).ravel()
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-12)


@pytest.mark.parametrize("rotation", [False, True])
def test_drag_opposes_vehicle_motion(params, arm_wrench_n, rotation):
    """Arm fixed (qd = 0), vehicle moving through still water: the drag part of tau_m
    (arm_wrench with rho set minus with Cd = 0) does negative power on the vehicle, wrench . nu < 0.
    (Every link point moves with the rigid vehicle, so each element's power is -k |v_n|^3 <= 0.)"""
    p = params.vector()
    p_nodrag = params.replace({"env.Cd": 0.0}).vector()
    f = arm_wrench_n[5]
    z = np.zeros(6)
    for eta, nu, q, _ in _moving_states(params, np.random.default_rng(2 + rotation), 30):
        if not rotation:
            nu[3:] = 0.0
        drag = np.array(f(eta, nu, z, q, z, z, 1, p)).ravel() - np.array(f(eta, nu, z, q, z, z, 1, p_nodrag)).ravel()
        power = drag @ nu
        assert power < -1e-6 * np.linalg.norm(drag) * np.linalg.norm(nu), power
        if not rotation:  # pure translation: the drag force has a component against the velocity
            assert drag[:3] @ nu[:3] < 0
    # scaling: drag is quadratic in speed (no linear term): doubling nu gives 4x the wrench
    eta, nu, q, _ = next(_moving_states(params, np.random.default_rng(9), 1))
    d1 = np.array(f(eta, nu, z, q, z, z, 0, p)).ravel() - np.array(f(eta, nu, z, q, z, z, 0, p_nodrag)).ravel()
    d2 = np.array(f(eta, 2 * nu, z, q, z, z, 0, p)).ravel() - np.array(f(eta, 2 * nu, z, q, z, z, 0, p_nodrag)).ravel()
    np.testing.assert_allclose(d2, 4 * d1, rtol=1e-9, atol=1e-9 * np.abs(d1).max())


def test_normal_basis_is_right_handed_and_orthonormal():
    rng = np.random.default_rng(11)
    us = [np.eye(3)[i] for i in range(3)] + [-np.eye(3)[i] for i in range(3)] + list(rng.normal(size=(20, 3)))
    for u in us:
        u = u / np.linalg.norm(u)
        e1, e2 = (np.array(e).ravel() for e in hydro.normal_basis(ca.DM(u)))
        B = np.column_stack([u, e1, e2])
        np.testing.assert_allclose(B.T @ B, np.eye(3), atol=1e-15)
        assert np.linalg.det(B) == pytest.approx(1.0, abs=1e-14)


def test_planar_drag_equals_link_drag():
    """The 2-D form of the integrals gives link_drag's force and moment (independent 3-D code)."""
    rng = np.random.default_rng(12)
    rho, Cd, D = 1027.77, 1.1, 0.09
    for _ in range(20):
        s, v, w = rng.normal(size=3) * 0.4, rng.normal(size=3), rng.normal(size=3)
        f_ref, n_ref = (np.array(o).ravel() for o in hydro.link_drag(rho, Cd, D, ca.DM(s), ca.DM(v), ca.DM(w), 5))
        L = np.linalg.norm(s)
        u = s / L
        e1, e2 = (np.array(e).ravel() for e in hydro.normal_basis(ca.DM(u)))
        a = ca.DM([e1 @ v, e2 @ v])
        b = ca.DM([e2 @ w, -(e1 @ w)])
        f2, m2 = (np.array(o).ravel() for o in hydro.planar_drag(-0.5 * rho * Cd * D, L, a, b, 5))
        np.testing.assert_allclose(f2[0] * e1 + f2[1] * e2, f_ref, rtol=0, atol=1e-13 * np.abs(f_ref).max())
        np.testing.assert_allclose(m2[0] * e2 - m2[1] * e1, n_ref, rtol=0, atol=1e-13 * np.abs(n_ref).max())
