"""Checks of the URDF reference itself (tests/pinocchio_urdf.py, tests/urdf_arms.py), on today's code.

1. Haidou-1's arm written as URDF from its DH table (``urdf_arms.haidou1_urdf``) and read by Pinocchio
   equals the DH-built reference (tests/pinocchio_model.py) to 1e-12: the arm's wrench on the vehicle,
   the mass matrix, the forward dynamics with prescribed joint accelerations. So the URDF reference,
   the DH-to-URDF translation and the two references' conventions agree.
2. The same reference against today's compiled-from-DH model (``plant['arm_wrench']``, ``uvms_rhs``):
   1e-9, like test_arm_pinocchio.py / test_uvms_pinocchio.py.
3. Random URDF arms (``urdf_arms.random_arm``): what Pinocchio's URDF reader builds equals a Pinocchio
   model assembled by hand from the drawn numbers with the URDF semantics written in urdf_arms.py
   (joint = Trans(xyz) Rot(rpy) Rot(axis, q), inertial frame, fixed joints merged, continuous joints);
   the static wrench is the arm's weight; the generated system file is well formed.
"""

from __future__ import annotations

import tomllib
import re

import numpy as np
import pinocchio as pin
import pytest

import pinocchio_model as pm
import pinocchio_urdf as pu
import urdf_arms as ua

TOL = 1e-12
RTOL = 1e-9


def _rel(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(b))


def _vehicle_tensor(p) -> np.ndarray:
    """The vehicle's inertia tensor about the body origin from Fossen's Ixx..Ixz (-Ixy off the diagonal)."""
    return np.array([[p["vehicle.Ixx"], -p["vehicle.Ixy"], -p["vehicle.Ixz"]],
                     [-p["vehicle.Ixy"], p["vehicle.Iyy"], -p["vehicle.Iyz"]],
                     [-p["vehicle.Ixz"], -p["vehicle.Iyz"], p["vehicle.Izz"]]])


def haidou1_reference(p) -> pu.Ref:
    """Haidou-1 (vehicle + arm) from the URDF written from its DH table: the mount has R^b_0 = I."""
    return pu.build(ua.haidou1_urdf(p), [p["arm.mount.x"], p["arm.mount.y"], p["arm.mount.z"]], [0.0, 0.0, 0.0],
                    p["vehicle.m"], _vehicle_tensor(p), [p["vehicle.xG"], p["vehicle.yG"], p["vehicle.zG"]],
                    g=p["env.g"])


@pytest.fixture(scope="module")
def ref(dry):
    return haidou1_reference(dry)


def _limits(p, n=6):
    return (np.array([p[f"arm.joint{i}.qmin"] for i in range(1, n + 1)]),
            np.array([p[f"arm.joint{i}.qmax"] for i in range(1, n + 1)]))


_state = pu.random_state


# ---- 1. URDF reference == DH reference ---------------------------------------------------------------


def test_haidou1_urdf_structure(dry, ref):
    model = pin.buildModelFromXML(ua.haidou1_urdf(dry))
    assert model.njoints == 7 and model.nq == 6
    assert [model.names[j] for j in range(1, 7)] == [f"joint{i}" for i in range(1, 7)]
    qmin, qmax = _limits(dry)
    np.testing.assert_array_equal(model.lowerPositionLimit, qmin)
    np.testing.assert_array_equal(model.upperPositionLimit, qmax)
    assert sum(model.inertias[j].mass for j in range(1, 7)) == pytest.approx(59.0, rel=1e-15)
    np.testing.assert_allclose(ref.tool_point, [0, 0, dry["arm.tool.length"]], rtol=0, atol=1e-16)
    assert ref.tool_joint == ref.arm_joint_ids[-1]


@pytest.mark.parametrize("payload", [0.0, 0.5, 1.0])
def test_urdf_reference_equals_dh_reference(dry, ref, pin_models, payload):
    uv = pin_models[payload]
    mp = payload * dry["payload.mass"]
    rng = np.random.default_rng(100 + int(10 * payload))
    qmin, qmax = _limits(dry)
    worst_w = worst_M = worst_a = 0.0
    for _ in range(30):
        eta, nu, nud, q, qd, qdd = _state(rng, qmin, qmax)
        w_dh = pm.arm_wrench_on_vehicle(uv, eta, nu, nud, q, qd, qdd)
        w_urdf = pu.arm_wrench_on_vehicle(ref, eta, nu, nud, q, qd, qdd, payload_mass=mp)
        worst_w = max(worst_w, _rel(w_urdf, w_dh))
        qpin = pm.configuration(eta, q)
        M_dh = pin.crba(uv.model, uv.data, qpin)
        M_dh = np.triu(M_dh) + np.triu(M_dh, 1).T
        with pu._payload(ref, mp):
            M_urdf = pu.mass_matrix(ref, pu.configuration(ref, eta, q))
        worst_M = max(worst_M, np.abs(M_urdf - M_dh).max() / np.abs(M_dh).max())
        # forward dynamics with prescribed qdd, as test_uvms_pinocchio.py solves it on the DH model
        w_ext = 300 * rng.normal(size=6)
        b = pin.rnea(uv.model, uv.data, qpin, np.concatenate([nu, qd]), np.concatenate([np.zeros(6), qdd]))[:6]
        a_dh = np.linalg.solve(M_dh[:6, :6], w_ext - b)
        a_urdf = pu.vehicle_accel(ref, eta, nu, q, qd, qdd, w_ext, payload_mass=mp)
        worst_a = max(worst_a, _rel(a_urdf, a_dh))
    print(f"payload {payload}: wrench {worst_w:.1e}, M {worst_M:.1e}, nu_dot {worst_a:.1e}")
    assert worst_w < TOL and worst_M < TOL and worst_a < TOL
    # the payload context restores the tool body
    assert ref.model.inertias[ref.tool_joint].mass == pytest.approx(dry["arm.link6.mass"], rel=1e-15)


def test_urdf_reference_with_buoyancy_forces(params):
    """In water at rest, buoyancy as external forces (test_arm_pinocchio.py's way) on both references."""
    ref_w = haidou1_reference(params)
    uv = pm.build(params, payload=1.0)
    rho, g = params["env.rho"], params["env.g"]
    rng = np.random.default_rng(105)
    qmin, qmax = _limits(params)
    z = np.zeros(6)
    for _ in range(10):
        eta, _, nud, q, _, qdd = _state(rng, qmin, qmax)
        out = []
        for model, data, ids, qpin in ((uv.model, uv.data, uv.arm_joint_ids, pm.configuration(eta, q)),
                                       (ref_w.model, ref_w.data, ref_w.arm_joint_ids, pu.configuration(ref_w, eta, q))):
            pin.forwardKinematics(model, data, qpin)
            fext = [pin.Force.Zero() for _ in range(model.njoints)]
            for i, jid in enumerate(ids, start=1):
                R = data.oMi[jid].rotation
                f = R.T @ np.array([0.0, 0.0, -rho * params[f"arm.link{i}.volume"] * g])
                fext[jid] = pin.Force(f, np.cross(0.5 * uv.link_vectors[i - 1], f))
                if i == 6:
                    fp = R.T @ np.array([0.0, 0.0, -rho * params["payload.volume"] * g])
                    fext[jid] = fext[jid] + pin.Force(fp, np.cross(uv.tool, fp))
            out.append(fext)
        pin.rnea(uv.model, uv.data, pm.configuration(eta, q), np.zeros(12), np.concatenate([nud, qdd]), out[0])
        f1 = uv.data.liMi[uv.arm_joint_ids[0]].act(uv.data.f[uv.arm_joint_ids[0]])
        w_dh = -np.concatenate([f1.linear, f1.angular])
        w_urdf = pu.arm_wrench_on_vehicle(ref_w, eta, z, nud, q, z, qdd, payload_mass=params["payload.mass"],
                                          fext=out[1])
        assert _rel(w_urdf, w_dh) < TOL


# ---- 2. URDF reference == today's model --------------------------------------------------------------


@pytest.mark.parametrize("payload", [0.0, 1.0])
def test_urdf_reference_matches_current_arm_wrench(plant, dry, ref, payload):
    p = dry.vector()
    rng = np.random.default_rng(110 + int(payload))
    qmin, qmax = _limits(dry)
    worst = 0.0
    for _ in range(20):
        s = _state(rng, qmin, qmax)
        got = np.array(plant["arm_wrench"](*s, payload, p)).ravel()
        worst = max(worst, _rel(got, pu.arm_wrench_on_vehicle(ref, *s, payload_mass=payload * dry["payload.mass"])))
    assert worst < RTOL, worst


def test_urdf_reference_matches_current_uvms_rhs(plant, dry, ref):
    """uvms_rhs at rho = 0: buoyancy B = (m + excess) g at r_B, the model's trim at the stow pose (from
    the reference's static wrench), tau; Haidou-1's derivatives are per rho, so no fluid is left."""
    p = dry.vector()
    q_stow = np.array([dry[f"arm.stow.q{i}"] for i in range(1, 7)])
    trim = pu.static_trim(ref, q_stow)
    B = (dry["vehicle.m"] + dry["vehicle.buoyancy_excess"]) * dry["env.g"]
    rB = [dry["vehicle.xB"], dry["vehicle.yB"], dry["vehicle.zB"]]
    rng = np.random.default_rng(120)
    qmin, qmax = _limits(dry)
    for payload in (0.0, 0.5):
        for _ in range(15):
            eta, nu, _, q, qd, qdd = _state(rng, qmin, qmax)
            tau = 300 * rng.normal(size=6)
            xd = np.array(plant["uvms_rhs"](np.concatenate([eta, nu]), tau, q, qd, qdd, payload, p)).ravel()
            w = pu.buoyancy_wrench(B, rB, eta) + pu.trim_wrench(trim, eta) + tau
            nud = pu.vehicle_accel(ref, eta, nu, q, qd, qdd, w, payload_mass=payload * dry["payload.mass"])
            assert _rel(xd[6:], nud) < RTOL
            assert _rel(xd[:6], pm.J_eta(eta) @ nu) < RTOL


# ---- 3. random URDF arms -----------------------------------------------------------------------------


def _by_hand(arm: ua.RandomArm) -> pu.Ref:
    """The arm assembled with Pinocchio's API from the drawn numbers (no URDF reader): each movable joint
    placed by the product of the fixed transforms since the previous movable joint and its own origin,
    revolute about its axis; a fixed child link's inertia merged into its moving body."""
    model = pin.Model()
    model.gravity.linear = np.array([0.0, 0.0, 9.81])
    model.gravity.angular = np.zeros(3)
    m = arm.vehicle_mass
    S = pu.skew(arm.vehicle_com)
    root = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "vehicle")
    model.appendBodyToJoint(root, pin.Inertia(m, arm.vehicle_com, arm.vehicle_inertia_origin + m * S @ S),
                            pin.SE3.Identity())
    links = {lk.name: lk for lk in arm.links}
    # where each link sits: (joint id of its body, placement of the link frame in that joint's frame)
    where = {arm.base_link: (root, pin.SE3(pu.rpy_matrix(arm.mount_rpy), np.asarray(arm.mount_xyz, float)))}
    ids = []
    for j in arm.joints:
        parent_jid, parent_M = where[j.parent]
        origin = pin.SE3(pu.rpy_matrix(j.rpy), np.asarray(j.xyz, float))
        if j.type == "fixed":
            where[j.child] = (parent_jid, parent_M * origin)
        else:
            jid = model.addJoint(parent_jid, pin.JointModelRevoluteUnaligned(np.asarray(j.axis, float)),
                                 parent_M * origin, j.name)
            ids.append(jid)
            where[j.child] = (jid, pin.SE3.Identity())
        lk = links[j.child]
        if lk.mass is not None:
            jid, M = where[j.child]
            model.appendBodyToJoint(jid, pin.Inertia(lk.mass, lk.com, lk.inertia_link()), M)
    tool_jid, tool_M = where[arm.tool_link]
    return pu.Ref(model, model.createData(), ids, [ids[0]], tool_jid, tool_M.translation.copy(),
                  pin.Inertia(model.inertias[tool_jid]), len(ids))


ARMS = ua.ARM_CASES
_arm = ua.case_arm


_urdf_ref = pu.build_for


@pytest.mark.parametrize("n,variant", ARMS)
def test_random_urdf_read_as_written(n, variant):
    arm = _arm(n, variant)
    ref, hand = _urdf_ref(arm), _by_hand(arm)
    assert ref.n_joints == hand.n_joints == n
    assert [ref.model.names[j] for j in ref.arm_joint_ids] == [f"joint{i}" for i in range(1, n + 1)]
    if variant != "plain":
        assert ref.model.joints[ref.arm_joint_ids[-1]].nq == 2  # continuous: (cos, sin)
    np.testing.assert_allclose(ref.tool_point, hand.tool_point, rtol=0, atol=1e-14)
    assert ref.tool_joint == ref.arm_joint_ids[-1] and hand.tool_joint == hand.arm_joint_ids[-1]
    rng = np.random.default_rng(n)
    for _ in range(10):
        s = _state(rng, arm.qmin, arm.qmax)
        mp = rng.uniform(0, arm.payload_mass)
        w_ref = pu.arm_wrench_on_vehicle(ref, *s, payload_mass=mp)
        w_hand = pu.arm_wrench_on_vehicle(hand, *s, payload_mass=mp)
        assert _rel(w_ref, w_hand) < TOL
        eta, nu, _, q, qd, qdd = s
        tau = 30 * rng.normal(size=6)
        a_ref = pu.vehicle_accel(ref, eta, nu, q, qd, qdd, tau, payload_mass=mp)
        assert _rel(a_ref, pu.vehicle_accel(hand, eta, nu, q, qd, qdd, tau, payload_mass=mp)) < TOL


@pytest.mark.parametrize("n,variant", ARMS[::3])
def test_random_arm_static_wrench_is_its_weight(n, variant):
    """Level and at rest: the arm presses on the vehicle with its weight (all links + merged flanges +
    payload), and the moment is that of the weight at the arm's centre of mass, in {b}."""
    arm = _arm(n, variant)
    ref = _urdf_ref(arm)
    mass = sum(lk.mass for lk in arm.links if lk.mass is not None)
    rng = np.random.default_rng(7)
    z = np.zeros(6)
    for _ in range(5):
        q = _state(rng, arm.qmin, arm.qmax)[3]
        w = pu.arm_wrench_on_vehicle(ref, z, z, z, q, np.zeros(n), np.zeros(n), payload_mass=arm.payload_mass)
        qpin = pu.configuration(ref, z, q)
        pin.forwardKinematics(ref.model, ref.data, qpin)
        first = sum(ref.model.inertias[j].mass * ref.data.oMi[j].act(ref.model.inertias[j].lever)
                    for j in ref.arm_joint_ids)
        first = first + arm.payload_mass * ref.data.oMi[ref.tool_joint].act(ref.tool_point)
        W = (mass + arm.payload_mass) * 9.81
        np.testing.assert_allclose(w[:3], [0, 0, W], rtol=0, atol=1e-12 * W)
        np.testing.assert_allclose(w[3:], np.cross(first, [0, 0, 9.81]), rtol=0, atol=1e-12 * W)


@pytest.mark.parametrize("n", [1, 4, 7])
def test_random_system_file_is_well_formed(tmp_path, n):
    arm = ua.random_arm(np.random.default_rng(n), n, fixed_joint=True)
    path = arm.write(tmp_path)
    assert (tmp_path / arm.urdf_name).read_text() == arm.urdf
    doc = tomllib.loads(path.read_text())
    assert doc["system"]["name"] == f"urdf_arm_{n}"
    assert doc["arm"]["urdf"] == arm.urdf_name and doc["arm"]["tool_link"] == "tool_link"
    assert set(doc["arm"]["stow"]) == {f"q{i}" for i in range(1, n + 1)}
    assert set(doc["arm"]["hydro"]) == {f"link{i}" for i in range(1, n + 1)}
    assert set(doc["arm"]["mount"]) == {"x", "y", "z", "roll", "pitch", "yaw"}
    units = doc["thrusters"]["unit"]
    assert len(units) == 8
    B = np.column_stack([np.concatenate([d, np.cross(p, d)]) for p, d in
                         ((np.array(u["position"]["value"]), np.array(u["direction"]["value"])) for u in units)])
    assert np.linalg.matrix_rank(B) == 6
    v = doc["vehicle"]
    I = np.array([[v["Ixx"]["value"], -v["Ixy"]["value"], -v["Ixz"]["value"]],
                  [-v["Ixy"]["value"], v["Iyy"]["value"], -v["Iyz"]["value"]],
                  [-v["Ixz"]["value"], -v["Iyz"]["value"], v["Izz"]["value"]]])
    np.testing.assert_array_equal(I, arm.vehicle_inertia_origin)
    assert np.linalg.eigvalsh(I).min() > 0
    for lk in arm.links:
        if lk.mass is not None:  # realisable: positive moments meeting the triangle inequality
            e = np.sort(np.linalg.eigvalsh(lk.inertia_local))
            assert e[0] > 0 and e[0] + e[1] > e[2]
    for lo, hi, q0 in zip(arm.qmin, arm.qmax, arm.q_stow):
        assert lo < 0 < hi and lo < q0 < hi


def test_haidou1_form3_text(dry):
    """The form-3 Haidou-1 file: the shipped text with its DH arm replaced by the URDF and hydro cylinders."""
    shipped = ua.shipped_haidou1_text()
    text = ua.haidou1_form3_toml(shipped, dry)
    doc, orig = tomllib.loads(text), tomllib.loads(shipped)
    assert doc["system"]["name"] == "haidou1_urdf"
    assert set(doc["arm"]) == {"urdf", "base_link", "tool_link", "mount", "stow", "hydro"}
    for k in ("env", "vehicle", "hydro", "thrusters", "payload"):
        assert doc[k] == orig[k]
    assert doc["arm"]["mount"] == orig["arm"]["mount"] and doc["arm"]["stow"] == orig["arm"]["stow"]
    h = doc["arm"]["hydro"]["link2"]
    assert h["volume"]["value"] == dry["arm.link2.volume"] and h["drag_diameter"]["value"] == dry["arm.link2.diameter"]
    s = ua.haidou1_link_vectors(dry)
    np.testing.assert_array_equal(h["drag_to"]["value"], s[1])
    np.testing.assert_array_equal(h["cob"]["value"], 0.5 * s[1])
    # the shipped [system] section is renamed, not duplicated; a file without one gets one
    assert tomllib.loads(text)["system"]["description"] == orig["system"]["description"]
    bare = re.sub(r"(?ms)^\[system\]\n.*?(?=^\[)", "", shipped)
    assert "system" not in tomllib.loads(bare)
    assert tomllib.loads(ua.haidou1_form3_toml(bare, dry))["system"]["name"] == "haidou1_urdf"


def test_vehicle_alone_is_fossens_rigid_body(tmp_path):
    """The free-flyer convention against Fossen's rigid body written out (origin away from the CG):
    M_RB nu_dot + C_RB(nu) nu = tau + [f_g; r_G x f_g], f_g = R' [0, 0, m g], with
    M_RB = [[m I, -m S(r_G)], [m S(r_G), I_o]] and
    C_RB = [[m S(w), -m S(w) S(r_G)], [m S(r_G) S(w), -S(I_o w)]] (Fossen 2011, eq. 3.57-3.60)."""
    arm = ua.random_arm(np.random.default_rng(3), 0)
    ref = pu.build_for(arm)
    assert ref.n_joints == 0 and ref.model.nq == 7
    m, rG, I_o = arm.vehicle_mass, arm.vehicle_com, arm.vehicle_inertia_origin
    S = pu.skew
    M_RB = np.block([[m * np.eye(3), -m * S(rG)], [m * S(rG), I_o]])
    rng = np.random.default_rng(4)
    e = np.zeros(0)
    for _ in range(10):
        eta = np.concatenate([rng.normal(size=3), rng.uniform(-1, 1, 3)])
        nu, tau = rng.normal(size=6), 30 * rng.normal(size=6)
        w = nu[3:]
        C_RB = np.block([[m * S(w), -m * S(w) @ S(rG)], [m * S(rG) @ S(w), -S(I_o @ w)]])
        f_g = pu.R_zyx(*eta[3:]).T @ np.array([0.0, 0.0, m * 9.81])
        nud = np.linalg.solve(M_RB, tau + np.concatenate([f_g, np.cross(rG, f_g)]) - C_RB @ nu)
        assert _rel(pu.vehicle_accel(ref, eta, nu, e, e, e, tau), nud) < TOL
        assert not pu.arm_wrench_on_vehicle(ref, eta, nu, nud, e, e, e).any()
    np.testing.assert_array_equal(pu.trim_wrench(pu.static_trim(ref, e), eta), np.zeros(6))
    path = arm.write(tmp_path)
    doc = tomllib.loads(path.read_text())
    assert "arm" not in doc and "payload" not in doc and not (tmp_path / arm.urdf_name).exists()
