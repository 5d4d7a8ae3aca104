"""arm_wrench (RNEA on a moving base, docs/model.md §3) against Pinocchio's RNEA on a free-flying base.

Reference: ``pinocchio_model`` builds the same arm (modified DH, cylinder links, point payload) on a
free flyer; the wrench the arm exerts on the vehicle is minus the spatial force transmitted through
joint 1, moved to the COB. With ``env.rho = 0`` there is no fluid; with water, buoyancy is added to
the Pinocchio model as external forces at rest (no drag without relative motion).
Tolerance: 1e-9 relative, norm-wise, over random states.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import pinocchio_model as pm

RTOL = 1e-9
N_STATES = 50


def _joint_limits(params):
    qmin = np.array([params[f"arm.joint{i}.qmin"] for i in range(1, 7)])
    qmax = np.array([params[f"arm.joint{i}.qmax"] for i in range(1, 7)])
    return qmin, qmax


def _random_state(rng, params):
    qmin, qmax = _joint_limits(params)
    eta = np.concatenate([rng.normal(size=3), rng.uniform(-1, 1, 2), rng.uniform(-np.pi, np.pi, 1)])
    nu = rng.normal(size=6) * np.array([1, 1, 1, 0.5, 0.5, 0.5])
    nud = rng.normal(size=6)
    q = rng.uniform(qmin, qmax)
    qd = rng.normal(size=6)
    qdd = rng.normal(size=6) * 3
    return eta, nu, nud, q, qd, qdd


def _tau_m(plant, p, eta, nu, nud, q, qd, qdd, payload):
    return np.array(plant["arm_wrench"](eta, nu, nud, q, qd, qdd, payload, p)).ravel()


def _rel_err(got, ref):
    return np.linalg.norm(got - ref) / np.linalg.norm(ref)


def test_pinocchio_model_sanity(dry, pin_models):
    """The reference itself: total arm mass 59 kg (+ payload), and joint 1 sits at the mount."""
    uv = pin_models[0.0]
    masses = [uv.model.inertias[j].mass for j in uv.arm_joint_ids]
    assert sum(masses) == pytest.approx(59.0, rel=1e-15)
    assert pin_models[1.0].model.inertias[uv.arm_joint_ids[-1]].mass == pytest.approx(5.0 + 3.0, rel=1e-15)
    np.testing.assert_allclose(uv.model.jointPlacements[uv.arm_joint_ids[0]].translation, [1.6, 0, 0.45])
    # the mass matrix of a rigid multibody is symmetric positive definite
    M = pin.crba(uv.model, uv.data, pm.configuration(np.zeros(6), np.deg2rad([90, 90, -90, 0, 90, 0])))
    M = np.triu(M) + np.triu(M, 1).T
    assert np.linalg.eigvalsh(M).min() > 0


@pytest.mark.parametrize("payload", [0.0, 0.5, 1.0])
def test_arm_wrench_matches_pinocchio_dry(plant, dry, pin_models, payload):
    p = dry.vector()
    uv = pin_models[payload]
    rng = np.random.default_rng(10 + int(10 * payload))
    worst = 0.0
    for _ in range(N_STATES):
        s = _random_state(rng, dry)
        ref = pm.arm_wrench_on_vehicle(uv, *s)
        got = _tau_m(plant, p, *s, payload)
        worst = max(worst, _rel_err(got, ref))
    print(f"payload {payload}: max relative error {worst:.2e}")
    assert worst < RTOL, f"max relative error {worst:.3e}"


def test_arm_wrench_affine_in_nud(plant, dry, pin_models):
    """The arm's reaction is affine in nu_dot with the same slope as Pinocchio's mass-matrix block:
    d tau_m / d nu_dot = -(M_full[0:6, 0:6] - M_vehicle) (the arm's share of the base inertia)."""
    p = dry.vector()
    uv = pin_models[0.0]
    rng = np.random.default_rng(20)
    for _ in range(5):
        eta, nu, _, q, qd, qdd = _random_state(rng, dry)
        base = _tau_m(plant, p, eta, nu, np.zeros(6), q, qd, qdd, 0.0)
        Jm = np.column_stack([_tau_m(plant, p, eta, nu, e, q, qd, qdd, 0.0) - base for e in np.eye(6)])
        M = pin.crba(uv.model, uv.data, pm.configuration(eta, q))
        M = np.triu(M) + np.triu(M, 1).T
        Mv = uv.model.inertias[1].matrix()  # the vehicle body's spatial inertia at the COB
        np.testing.assert_allclose(-Jm, M[:6, :6] - Mv, rtol=0, atol=RTOL * np.abs(M[:6, :6] - Mv).max())


def test_static_weight_dry(plant, dry):
    """At rest, level, rho = 0: the arm presses on the vehicle with its weight in air, 59 g N (z down)."""
    z = np.zeros(6)
    rng = np.random.default_rng(30)
    qmin, qmax = _joint_limits(dry)
    for _ in range(5):
        tm = _tau_m(plant, dry.vector(), z, z, z, rng.uniform(qmin, qmax), z, z, 0.0)
        g = dry["env.g"]
        np.testing.assert_allclose(tm[:3], [0, 0, 59.0 * g], rtol=0, atol=1e-10 * 59 * g)
        tm1 = _tau_m(plant, dry.vector(), z, z, z, rng.uniform(qmin, qmax), z, z, 1.0)
        np.testing.assert_allclose(tm1[:3], [0, 0, 62.0 * g], rtol=0, atol=1e-10 * 62 * g)


def test_static_weight_in_water(plant, params):
    """In water: weight in water 36.6 g N (docs/model.md §3; the link table meets it to 4.5e-6 relative),
    and the payload adds 2 g N (3 kg in air, 2 kg weight in water)."""
    z = np.zeros(6)
    g = params["env.g"]
    p = params.vector()
    rng = np.random.default_rng(31)
    qmin, qmax = _joint_limits(params)
    for _ in range(5):
        q = rng.uniform(qmin, qmax)
        t0 = _tau_m(plant, p, z, z, z, q, z, z, 0.0)
        t1 = _tau_m(plant, p, z, z, z, q, z, z, 1.0)
        assert abs(t0[0]) < 1e-9 and abs(t0[1]) < 1e-9
        assert t0[2] == pytest.approx(36.6 * g, rel=1e-5)
        assert t1[2] - t0[2] == pytest.approx(2.0 * g, rel=1e-8)


def test_buoyancy_matches_pinocchio_with_external_forces(plant, params, pin_models):
    """Without relative motion there is no drag: tau_m in water equals Pinocchio's RNEA with each link's
    buoyancy rho V_i g applied upward (world) at its centre, at any attitude, nu_dot and qdd."""
    p = params.vector()
    rho, g = params["env.rho"], params["env.g"]
    uv = pin_models[1.0]
    model, data = uv.model, uv.data
    rng = np.random.default_rng(32)
    z = np.zeros(6)
    for _ in range(20):
        eta, _, nud, q, _, qdd = _random_state(rng, params)
        qpin = pm.configuration(eta, q)
        pin.forwardKinematics(model, data, qpin)
        fext = [pin.Force.Zero() for _ in range(model.njoints)]
        for i, jid in enumerate(uv.arm_joint_ids, start=1):
            R = data.oMi[jid].rotation
            f_loc = R.T @ np.array([0.0, 0.0, -rho * params[f"arm.link{i}.volume"] * g])
            c = 0.5 * uv.link_vectors[i - 1]
            fext[jid] = pin.Force(f_loc, np.cross(c, f_loc))
            if i == 6:  # payload volume at the tool point
                fp = R.T @ np.array([0.0, 0.0, -rho * params["payload.volume"] * g])
                fext[jid] = fext[jid] + pin.Force(fp, np.cross(uv.tool, fp))
        pin.rnea(model, data, qpin, np.zeros(12), np.concatenate([nud, qdd]), fext)
        j1 = uv.arm_joint_ids[0]
        fr = data.liMi[j1].act(data.f[j1])
        ref = -np.concatenate([fr.linear, fr.angular])
        got = _tau_m(plant, p, eta, z, nud, q, z, qdd, 1.0)
        assert _rel_err(got, ref) < RTOL
