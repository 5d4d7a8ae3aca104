"""uvms_rhs (exactly coupled vehicle + arm, docs/model.md §2-3) against Pinocchio forward dynamics, rho = 0.

With ``env.rho = 0`` the vehicle has no added mass and no damping; what remains is rigid-body
dynamics of the vehicle + arm tree under gravity plus three external wrenches on the vehicle body:
its buoyancy B = (m + buoyancy_excess) g (world-up at the COB; B does not depend on rho in this model),
the docs/model.md §3 trim (computed here from Pinocchio's own static arm wrench at q0), and the body wrench tau.
The joints' accelerations are prescribed, so only the base acceleration is solved for:
``M[0:6,0:6] nu_dot = f_ext - (nle + M[0:6,6:12] qdd)[0:6]``, where the bracket is Pinocchio's RNEA
with base acceleration 0 and joint accelerations qdd (free-flyer rows: no actuation on the base).
Tolerance: 1e-9 relative, norm-wise, over random states.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import pinocchio_model as pm

RTOL = 1e-9
N_STATES = 30


@pytest.fixture(scope="module")
def trim_static(dry, pin_models):
    """[F_z, M_x, M_y] of the arm's static wrench at q0, level, at rest, no payload (Pinocchio)."""
    q0 = np.array([dry[f"arm.stow.q{i}"] for i in range(1, 7)])
    np.testing.assert_allclose(np.rad2deg(q0), [90, 90, -90, 0, 90, 0], atol=1e-12)
    z = np.zeros(6)
    w = pm.arm_wrench_on_vehicle(pin_models[0.0], z, z, z, q0, z, z)
    assert abs(w[0]) < 1e-9 and abs(w[1]) < 1e-9 and abs(w[5]) < 1e-9
    return w[2], w[3], w[4]


def _base_external_wrench(dry, trim_static, eta, tau):
    """Buoyancy + trim + tau on the vehicle body, in {b} about the COB."""
    Fz, Mx, My = trim_static
    R = pm.R_zyx(*eta[3:6])
    B = (dry["vehicle.m"] + dry["vehicle.buoyancy_excess"]) * dry["env.g"]
    f_B = R.T @ np.array([0.0, 0.0, -B])  # r_B = 0: no moment
    r_t = np.array([-My / Fz, Mx / Fz, 0.0])
    f_t = R.T @ np.array([0.0, 0.0, -Fz])
    m_t = np.cross(r_t, f_t)
    return np.concatenate([f_B + f_t + tau[:3], m_t + tau[3:]])


def _pinocchio_nud(uv, eta, nu, q, qd, qdd, w_ext):
    model, data = uv.model, uv.data
    qpin = pm.configuration(eta, q)
    v = np.concatenate([nu, qd])
    b = pin.rnea(model, data, qpin, v, np.concatenate([np.zeros(6), qdd]))[:6]  # nle + M[:6,6:] qdd
    M = pin.crba(model, data, qpin)
    M = np.triu(M) + np.triu(M, 1).T
    return np.linalg.solve(M[:6, :6], w_ext - b)


def test_pinocchio_forward_dynamics_consistent(dry, pin_models, trim_static):
    """Check of the reference itself: the base acceleration above, fed back to Pinocchio's RNEA with
    the external wrench, gives zero generalised force on the free-flyer (no actuator on the base)."""
    uv = pin_models[1.0]
    rng = np.random.default_rng(40)
    eta = np.concatenate([rng.normal(size=3), rng.uniform(-1, 1, 3)])
    nu, q, qd, qdd, tau = (rng.normal(size=6) for _ in range(5))
    w = _base_external_wrench(dry, trim_static, eta, 100 * tau)
    nud = _pinocchio_nud(uv, eta, nu, q, qd, qdd, w)
    fext = [pin.Force.Zero() for _ in range(uv.model.njoints)]
    fext[1] = pin.Force(w[:3], w[3:])
    tq = pin.rnea(uv.model, uv.data, pm.configuration(eta, q), np.concatenate([nu, qd]),
                  np.concatenate([nud, qdd]), fext)
    assert np.abs(tq[:6]).max() < 1e-9 * np.abs(w).max()


@pytest.mark.parametrize("payload", [0.0, 0.5, 1.0])
def test_uvms_rhs_matches_pinocchio(plant, dry, pin_models, trim_static, payload):
    p = dry.vector()
    uv = pin_models[payload]
    qmin = np.array([dry[f"arm.joint{i}.qmin"] for i in range(1, 7)])
    qmax = np.array([dry[f"arm.joint{i}.qmax"] for i in range(1, 7)])
    rng = np.random.default_rng(41 + int(10 * payload))
    worst_nud = worst_etad = 0.0
    for _ in range(N_STATES):
        eta = np.concatenate([rng.normal(size=3), rng.uniform(-1, 1, 2), rng.uniform(-np.pi, np.pi, 1)])
        nu = rng.normal(size=6) * np.array([1, 1, 1, 0.5, 0.5, 0.5])
        tau = rng.normal(size=6) * 300
        q = rng.uniform(qmin, qmax)
        qd = rng.normal(size=6)
        qdd = rng.normal(size=6) * 3
        xd = np.array(plant["uvms_rhs"](np.concatenate([eta, nu]), tau, q, qd, qdd, payload, p)).ravel()
        w = _base_external_wrench(dry, trim_static, eta, tau)
        nud_ref = _pinocchio_nud(uv, eta, nu, q, qd, qdd, w)
        etad_ref = pm.J_eta(eta) @ nu
        worst_nud = max(worst_nud, np.linalg.norm(xd[6:] - nud_ref) / np.linalg.norm(nud_ref))
        worst_etad = max(worst_etad, np.linalg.norm(xd[:6] - etad_ref) / np.linalg.norm(etad_ref))
    print(f"payload {payload}: nu_dot rel err {worst_nud:.2e}, eta_dot rel err {worst_etad:.2e}")
    assert worst_nud < RTOL and worst_etad < RTOL


@pytest.mark.parametrize("medium", ["dry", "water"])
def test_trim_cancels_arm_at_q0(plant, params, dry, medium):
    """At q0, level, at rest, no payload, tau cancelling the net buoyancy: the coupled vehicle does not
    accelerate (the trim exactly balances the arm's static wrench, docs/model.md §3), in air and in water."""
    pr = params if medium == "water" else dry
    p = pr.vector()
    q0 = np.array([pr[f"arm.stow.q{i}"] for i in range(1, 7)])
    g = pr["env.g"]
    tau = np.array([0, 0, pr["vehicle.buoyancy_excess"] * g, 0, 0, 0])  # B - W, pushing down (+z)
    z = np.zeros(6)
    xd = np.array(plant["uvms_rhs"](np.zeros(12), tau, q0, z, z, 0.0, p)).ravel()
    assert np.abs(xd).max() < 1e-12
