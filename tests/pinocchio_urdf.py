"""Reference vehicle + arm built ONLY by Pinocchio from a URDF text and a mount pose (no arvcas code).

The independent side of the system-file checks for any arm: Pinocchio reads
the URDF (its own parser: joint origins, axes, fixed-joint merging, inertials), and the arm's joints are
grafted onto a free-flyer root that is the vehicle body. Conventions are those of
tests/pinocchio_model.py (the Haidou-1 DH reference), unchanged:

- world {n} = NED, gravity +g along z; the free-flyer's frame is the vehicle body frame {b}, its origin
  the body origin (Haidou-1: the COB; a system file may put it elsewhere);
- configuration ``[x y z qx qy qz qw, arm]``: the body origin in {n} and the quaternion of
  R^n_b = Rz(psi) Ry(theta) Rx(phi) (scalar last); a ``continuous`` joint is (cos q, sin q) in Pinocchio;
- free-flyer velocity ``[v; w]`` in the LOCAL (body) frame = Fossen's ``nu``; its acceleration is the
  time derivative of those components = Fossen's ``nu_dot``;
- the arm's base frame {0} (``base_link``) sits at the mount: p^b_0 = mount xyz,
  R^b_0 = Rz(yaw) Ry(pitch) Rx(roll) (docs/system-file.md ``[arm.mount]``);
- the payload is a point mass at the tool point (the origin of ``tool_link``) on the body that carries it.

Fluid forces are not in the model (use rho = 0, or add them as external forces).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

__all__ = ["Ref", "build", "build_for", "configuration", "velocity", "arm_wrench_on_vehicle", "vehicle_accel",
           "static_trim", "trim_wrench", "buoyancy_wrench", "R_zyx", "rpy_matrix", "skew", "mass_matrix"]


def R_zyx(phi: float, theta: float, psi: float) -> np.ndarray:
    """R^n_b = Rz(psi) Ry(theta) Rx(phi) (Fossen eq. 2.18), via scipy (intrinsic z-y'-x'')."""
    return Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix()


def rpy_matrix(rpy) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll): URDF's rpy and the system file's mount."""
    return R_zyx(*rpy)


def skew(a) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


@dataclass
class Ref:
    model: pin.Model
    data: pin.Data
    arm_joint_ids: list[int]  # the arm's movable joints in chain order (q order)
    root_joint_ids: list[int]  # arm joints whose parent is the vehicle body
    tool_joint: int  # the joint whose body carries the tool point
    tool_point: np.ndarray  # tool point in that joint's frame
    tool_body_inertia: pin.Inertia  # that body's inertia without payload
    n_joints: int


def build(urdf_text: str, mount_xyz, mount_rpy, vehicle_mass: float, vehicle_inertia_about_origin,
          vehicle_com, *, g: float = 9.81, base_link: str = "base_link", tool_link: str = "tool_link") -> Ref:
    """Vehicle (free flyer) + the URDF arm at the mount (``urdf_text=None``: the vehicle alone).

    ``vehicle_inertia_about_origin``: the 3x3 rotational inertia TENSOR about the body origin (its
    off-diagonal elements are Fossen's -Ixy, -Iyz, -Ixz); ``vehicle_com``: r_G in {b}.
    """
    arm = pin.buildModelFromXML(urdf_text) if urdf_text is not None else None
    model = pin.Model()
    model.gravity.linear = np.array([0.0, 0.0, g])  # NED: z down
    model.gravity.angular = np.zeros(3)

    m = float(vehicle_mass)
    rG = np.asarray(vehicle_com, float)
    I_o = np.asarray(vehicle_inertia_about_origin, float)
    S = skew(rG)
    root = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "vehicle")
    model.appendBodyToJoint(root, pin.Inertia(m, rG, I_o + m * S @ S), pin.SE3.Identity())

    if arm is None:  # the vehicle alone
        return Ref(model, model.createData(), [], [], root, np.zeros(3), pin.Inertia(model.inertias[root]), 0)
    base_fid = arm.getFrameId(base_link)
    if base_fid >= len(arm.frames) or arm.frames[base_fid].parentJoint != 0:
        raise ValueError(f"base_link {base_link!r} is not a link fixed to the URDF's root")
    mount = pin.SE3(rpy_matrix(mount_rpy), np.asarray(mount_xyz, float))
    b_M_universe = mount * arm.frames[base_fid].placement.inverse()  # URDF root in {b}

    new_id = {0: root}
    ids, roots = [], []
    for j in range(1, arm.njoints):
        parent = arm.parents[j]
        placement = arm.jointPlacements[j]
        if parent == 0:
            placement = b_M_universe * placement
        jid = model.addJoint(new_id[parent], arm.joints[j], placement, arm.names[j])
        model.appendBodyToJoint(jid, arm.inertias[j], pin.SE3.Identity())
        new_id[j] = jid
        ids.append(jid)
        if parent == 0:
            roots.append(jid)
    if any(arm.joints[j].nv != 1 for j in range(1, arm.njoints)):
        raise ValueError("the reference handles 1-dof joints only")

    tool_fid = arm.getFrameId(tool_link)
    if tool_fid >= len(arm.frames):
        raise ValueError(f"no link {tool_link!r} in the URDF")
    tf = arm.frames[tool_fid]
    tool_joint = new_id[tf.parentJoint]
    data = model.createData()
    return Ref(model, data, ids, roots, tool_joint, tf.placement.translation.copy(),
               pin.Inertia(model.inertias[tool_joint]), len(ids))


def configuration(ref: Ref, eta, q) -> np.ndarray:
    """Pinocchio configuration from Fossen's eta (NED position, zyx Euler angles) and the joint angles."""
    quat = Rotation.from_matrix(R_zyx(*eta[3:6])).as_quat()  # [x, y, z, w]
    out = [np.asarray(eta[:3], float), quat]
    for jid, qi in zip(ref.arm_joint_ids, q):
        nq = ref.model.joints[jid].nq
        out.append(np.array([qi]) if nq == 1 else np.array([np.cos(qi), np.sin(qi)]))
    return np.concatenate(out)


def velocity(nu, qd) -> np.ndarray:
    return np.concatenate([np.asarray(nu, float), np.asarray(qd, float)])


class _payload:
    """Context: the point payload added to the tool body's inertia, restored on exit."""

    def __init__(self, ref: Ref, mass: float, tool_point=None):
        self.ref, self.mass = ref, float(mass)
        self.point = ref.tool_point if tool_point is None else np.asarray(tool_point, float)

    def __enter__(self):
        if self.mass != 0.0 and self.ref.n_joints:
            self.ref.model.inertias[self.ref.tool_joint] = (
                self.ref.tool_body_inertia + pin.Inertia(self.mass, self.point, np.zeros((3, 3))))
        return self.ref

    def __exit__(self, *exc):
        self.ref.model.inertias[self.ref.tool_joint] = self.ref.tool_body_inertia
        return False


def arm_wrench_on_vehicle(ref: Ref, eta, nu, nud, q, qd, qdd, payload_mass: float = 0.0, tool_point=None,
                          fext=None) -> np.ndarray:
    """The wrench the arm (+ point payload) exerts ON the vehicle body, in {b} about the body origin,
    [force; moment]: minus the spatial forces the vehicle transmits through the arm's root joints
    (Pinocchio's RNEA on the free-flying base, gravity +z), expressed in the vehicle frame.
    ``fext``: optional external forces per joint (Pinocchio local frames), e.g. buoyancy."""
    model, data = ref.model, ref.data
    with _payload(ref, payload_mass, tool_point):
        args = (model, data, configuration(ref, eta, q), velocity(nu, qd), velocity(nud, qdd))
        pin.rnea(*args) if fext is None else pin.rnea(*args, fext)
        w = np.zeros(6)
        for j in ref.root_joint_ids:
            f = data.liMi[j].act(data.f[j])
            w -= np.concatenate([f.linear, f.angular])
    return w


def mass_matrix(ref: Ref, qpin) -> np.ndarray:
    M = pin.crba(ref.model, ref.data, qpin)
    return np.triu(M) + np.triu(M, 1).T


def vehicle_accel(ref: Ref, eta, nu, q, qd, qdd, body_wrench, payload_mass: float = 0.0,
                  tool_point=None) -> np.ndarray:
    """nu_dot of vehicle + arm under gravity and ``body_wrench`` (in {b} about the body origin) with the
    joint accelerations prescribed: M[0:6,0:6] nu_dot = w - (nle + M[0:6,6:] qdd)[0:6] (the bracket is
    RNEA with base acceleration 0: no actuation on the free flyer)."""
    model, data = ref.model, ref.data
    with _payload(ref, payload_mass, tool_point):
        qpin = configuration(ref, eta, q)
        b = pin.rnea(model, data, qpin, velocity(nu, qd), velocity(np.zeros(6), qdd))[:6]
        M = mass_matrix(ref, qpin)
    return np.linalg.solve(M[:6, :6], np.asarray(body_wrench, float) - b)


def static_trim(ref: Ref, q_stow) -> tuple[float, float, float]:
    """(F_z, M_x, M_y) of the arm's static wrench at the stow pose, level, at rest, no payload."""
    z = np.zeros(6)
    n = ref.n_joints
    w = arm_wrench_on_vehicle(ref, z, z, z, q_stow, np.zeros(n), np.zeros(n))
    return w[2], w[3], w[4]


def trim_wrench(trim, eta) -> np.ndarray:
    """docs/model.md §3 trim: a world-vertical upward force F_z at r_t = [-M_y/F_z, M_x/F_z, 0] in {b}."""
    Fz, Mx, My = trim
    if Fz == 0.0 and Mx == 0.0 and My == 0.0:  # nothing to trim (no arm)
        return np.zeros(6)
    R = R_zyx(*eta[3:6])
    r_t = np.array([-My / Fz, Mx / Fz, 0.0])
    f_t = R.T @ np.array([0.0, 0.0, -Fz])
    return np.concatenate([f_t, np.cross(r_t, f_t)])


def buoyancy_wrench(B: float, r_B, eta) -> np.ndarray:
    """The vehicle's buoyancy B (N, world-up) at r_B, in {b} about the body origin."""
    f = R_zyx(*eta[3:6]).T @ np.array([0.0, 0.0, -B])
    return np.concatenate([f, np.cross(np.asarray(r_B, float), f)])


def build_for(arm, g: float = 9.81) -> Ref:
    """:func:`build` from a ``urdf_arms.RandomArm`` (its URDF text, mount and vehicle)."""
    return build(arm.urdf if arm.n_joints else None, arm.mount_xyz, arm.mount_rpy, arm.vehicle_mass,
                 arm.vehicle_inertia_origin, arm.vehicle_com, g=g, base_link=arm.base_link, tool_link=arm.tool_link)


def random_state(rng, qmin, qmax):
    """A random (eta, nu, nud, q, qd, qdd) with q inside the limits (infinite limits: [-pi, pi])."""
    n = len(qmin)
    lo = np.where(np.isfinite(qmin), qmin, -np.pi)
    hi = np.where(np.isfinite(qmax), qmax, np.pi)
    eta = np.concatenate([rng.normal(size=3), rng.uniform(-1, 1, 2), rng.uniform(-np.pi, np.pi, 1)])
    nu = rng.normal(size=6) * np.array([1, 1, 1, 0.5, 0.5, 0.5])
    return eta, nu, rng.normal(size=6), rng.uniform(lo, hi), rng.normal(size=n), 3 * rng.normal(size=n)
