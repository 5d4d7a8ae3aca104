"""The vehicle + arm as a Pinocchio model, built from the same parameters but not from arvcas's code.

Independent reference for the CasADi graphs (docs/model.md §3): a free-flyer root for the vehicle body (its
frame at the COB, SNAME body axes; world = NED, so gravity is +g along z), then six revolute-Z joints
placed by Craig's modified DH. Only numbers come from :class:`arvcas.system.params.Params`; the DH
placements, link vectors, cylinder inertias and rotation matrices are computed here.

Pinocchio conventions used by the tests:
- configuration ``[x y z qx qy qz qw q1..q6]``: position of the COB in {n}, attitude quaternion of
  R^n_b (scalar last);
- free-flyer velocity ``[v; w]`` in the LOCAL (body) frame = Fossen's ``nu``; its acceleration is the
  time derivative of those local components = Fossen's ``nu_dot``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def R_zyx(phi: float, theta: float, psi: float) -> np.ndarray:
    """R^n_b = Rz(psi) Ry(theta) Rx(phi) (Fossen eq. 2.18), via scipy (intrinsic z-y'-x'')."""
    return Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix()


def T_theta(phi: float, theta: float) -> np.ndarray:
    """Euler-angle rates from body rates (Fossen eq. 2.29)."""
    cf, sf, ct, tt = np.cos(phi), np.sin(phi), np.cos(theta), np.tan(theta)
    return np.array([[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, sf / ct, cf / ct]])


def J_eta(eta) -> np.ndarray:
    J = np.zeros((6, 6))
    J[:3, :3] = R_zyx(*eta[3:6])
    J[3:, 3:] = T_theta(eta[3], eta[4])
    return J


def skew(a) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def cylinder_inertia(mass: float, diameter: float, s: np.ndarray) -> np.ndarray:
    """Solid cylinder along s, about its centre: I_axial = m r^2/2, I_transverse = m (3 r^2 + L^2)/12."""
    L = np.linalg.norm(s)
    u = s / L
    r = 0.5 * diameter
    I_ax = 0.5 * mass * r**2
    I_tr = mass * (3.0 * r**2 + L**2) / 12.0
    return I_tr * np.eye(3) + (I_ax - I_tr) * np.outer(u, u)


def dh_placement(a: float, alpha: float, d: float) -> pin.SE3:
    """Fixed part of Craig's modified DH, RotX(alpha) TransX(a) TransZ(d) (RotZ(q) is the joint)."""
    R = rot_x(alpha)
    return pin.SE3(R, np.array([a, 0.0, 0.0]) + R @ np.array([0.0, 0.0, d]))


@dataclass
class UVMS:
    model: pin.Model
    data: pin.Data
    arm_joint_ids: list[int]  # Pinocchio joint ids of arm joints 1..6 (root free-flyer is id 1)
    link_vectors: list[np.ndarray]  # s_i = P^i_{i+1}, link 6 to the tool point
    tool: np.ndarray  # tool point in frame {6}


def build(params, payload: float = 0.0) -> UVMS:
    """Vehicle + arm with a point payload of mass ``payload * payload.mass`` at the tool point.

    Fluid forces (buoyancy, drag, added mass) are not in the model: use it with ``env.rho = 0`` or add
    them as external forces.
    """
    p = params
    model = pin.Model()
    model.gravity.linear = np.array([0.0, 0.0, p["env.g"]])  # NED: z down
    model.gravity.angular = np.zeros(3)

    # vehicle body: free flyer at the COB
    m = p["vehicle.m"]
    rG = np.array([p["vehicle.xG"], p["vehicle.yG"], p["vehicle.zG"]])
    Ixx, Iyy, Izz = p["vehicle.Ixx"], p["vehicle.Iyy"], p["vehicle.Izz"]
    Ixy, Iyz, Ixz = p["vehicle.Ixy"], p["vehicle.Iyz"], p["vehicle.Ixz"]
    I_b = np.array([[Ixx, -Ixy, -Ixz], [-Ixy, Iyy, -Iyz], [-Ixz, -Iyz, Izz]])  # about the COB
    S = skew(rG)
    I_c = I_b + m * S @ S  # parallel axis: about the COM
    root = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "vehicle")
    model.appendBodyToJoint(root, pin.Inertia(m, rG, I_c), pin.SE3.Identity())

    # arm: DH table, link vectors s_i = P^i_{i+1} (translation of the next joint's placement)
    placements = []
    for i in range(1, 7):
        placements.append(dh_placement(p[f"arm.joint{i}.a"], p[f"arm.joint{i}.alpha"], p[f"arm.joint{i}.d"]))
    tool = np.array([0.0, 0.0, p["arm.tool.length"]])
    svec = [placements[i].translation.copy() for i in range(1, 6)] + [tool]
    mount = pin.SE3(np.eye(3), np.array([p["arm.mount.x"], p["arm.mount.y"], p["arm.mount.z"]]))

    parent = root
    ids = []
    for i in range(1, 7):
        placement = mount * placements[0] if i == 1 else placements[i - 1]
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f"joint{i}")
        s = svec[i - 1]
        mi = p[f"arm.link{i}.mass"]
        inertia = pin.Inertia(mi, 0.5 * s, cylinder_inertia(mi, p[f"arm.link{i}.diameter"], s))
        if i == 6 and payload != 0.0:
            inertia = inertia + pin.Inertia(payload * p["payload.mass"], tool, np.zeros((3, 3)))
        model.appendBodyToJoint(jid, inertia, pin.SE3.Identity())
        ids.append(jid)
        parent = jid
    return UVMS(model, model.createData(), ids, svec, tool)


def configuration(eta, q) -> np.ndarray:
    """Pinocchio configuration from Fossen's eta (NED position, zyx Euler angles) and joint angles."""
    quat = Rotation.from_matrix(R_zyx(*eta[3:6])).as_quat()  # [x, y, z, w]
    return np.concatenate([np.asarray(eta[:3], float), quat, np.asarray(q, float)])


def arm_wrench_on_vehicle(uv: UVMS, eta, nu, nud, q, qd, qdd) -> np.ndarray:
    """tau_m from Pinocchio's RNEA: minus the spatial force the vehicle transmits to link 1 through
    joint 1, moved to the vehicle frame (COB, body axes). Returns [force; moment]."""
    model, data = uv.model, uv.data
    pin.rnea(model, data, configuration(eta, q), np.concatenate([nu, qd]), np.concatenate([nud, qdd]))
    j1 = uv.arm_joint_ids[0]
    f_root = data.liMi[j1].act(data.f[j1])
    return -np.concatenate([f_root.linear, f_root.angular])
