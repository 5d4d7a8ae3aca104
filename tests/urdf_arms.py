"""Arms written as URDF for the tests: random serial revolute arms, and Haidou-1's arm from its DH table.

Nothing here uses arvcas's model code: the numbers are drawn (``random_arm``) or read from a parameter
mapping (``haidou1_urdf``), and written as URDF and system-file text (docs/system-file.md, form 3).
Every float is written with ``repr`` (shortest round-trip), so a reader gets back the very same doubles.

URDF semantics (the URDF spec): child = parent * Trans(xyz) * Rot(rpy) * Rot(axis, q), with
Rot(rpy) = Rz(yaw) Ry(pitch) Rx(roll); ``<inertial><origin>`` places the centre of mass and the frame
the ``<inertia>`` tensor is written in; ``ixy`` etc. are the tensor's own elements (I[0, 1] = ixy).

Haidou-1 (``haidou1_urdf``): Craig's modified DH joint i is T_{i-1,i} = TransX(a) RotX(alpha) RotZ(q)
TransZ(d). RotZ(q) and TransZ(d) commute (same axis), so T = Trans(a x + RotX(alpha) d z) RotX(alpha)
RotZ(q): the URDF joint i has origin xyz = [a, -sin(alpha) d, cos(alpha) d], rpy = [alpha, 0, 0],
axis z, and its child link frame IS DH frame {i} (after TransZ(d_i)); no shift moves to the next joint.
Link i is the cylinder from origin {i} to origin {i+1} (link 6 to the tool point [0, 0, L_tool]).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "RandomArm", "JointSpec", "LinkSpec", "random_arm", "realisable_inertia", "haidou1_urdf",
    "haidou1_hydro_toml", "haidou1_form3_toml", "shipped_haidou1_text",
    "ARM_CASES", "case_arm", "urdf_inertia_attrs", "bad_urdf",
]


def _f(x) -> str:
    return repr(float(x))


def _v(x) -> str:
    return " ".join(_f(e) for e in x)


def _toml_vec(x) -> str:
    return "[" + ", ".join(_f(e) for e in x) + "]"


def _entry(value, unit: str, source: str = "urdf_arms.py (random)") -> str:
    val = _toml_vec(value) if np.ndim(value) else _f(value)
    return f'{{ value = {val}, unit = "{unit}", source = "{source}" }}'


def rpy_matrix(rpy) -> np.ndarray:
    """Rot(rpy) = Rz(yaw) Ry(pitch) Rx(roll) (URDF; also docs/system-file.md [arm.mount])."""
    r, p, y = rpy
    return Rotation.from_euler("ZYX", [y, p, r]).as_matrix()


def realisable_inertia(rng, scale: float) -> np.ndarray:
    """A random physically realisable inertia tensor about the centre of mass.

    Principal moments from the second moments d_k = integral of x_k^2 dm > 0 along the principal axes,
    I_1 = d_2 + d_3 etc., which is exactly the set of moments meeting the (strict) triangle inequality;
    then a random rotation: R diag(I) R'.
    """
    d = rng.uniform(0.1, 1.0, 3) * scale
    principal = np.array([d[1] + d[2], d[0] + d[2], d[0] + d[1]])
    R = Rotation.random(random_state=rng).as_matrix()
    I = R @ np.diag(principal) @ R.T
    return 0.5 * (I + I.T)


def urdf_inertia_attrs(I) -> str:
    return (f'ixx="{_f(I[0, 0])}" iyy="{_f(I[1, 1])}" izz="{_f(I[2, 2])}" '
            f'ixy="{_f(I[0, 1])}" ixz="{_f(I[0, 2])}" iyz="{_f(I[1, 2])}"')


@dataclass
class LinkSpec:
    name: str
    mass: float | None = None  # None: no <inertial>
    com: np.ndarray | None = None  # in the link frame
    inertial_rpy: np.ndarray | None = None  # the frame the tensor is written in
    inertia_local: np.ndarray | None = None  # tensor about the com, in the inertial frame (as written)

    def inertia_link(self) -> np.ndarray:
        """The tensor about the com in the link frame."""
        R = rpy_matrix(self.inertial_rpy)
        return R @ self.inertia_local @ R.T

    def xml(self) -> str:
        if self.mass is None:
            return f'  <link name="{self.name}"/>\n'
        return (f'  <link name="{self.name}">\n    <inertial>\n'
                f'      <origin xyz="{_v(self.com)}" rpy="{_v(self.inertial_rpy)}"/>\n'
                f'      <mass value="{_f(self.mass)}"/>\n'
                f'      <inertia {urdf_inertia_attrs(self.inertia_local)}/>\n'
                f'    </inertial>\n  </link>\n')


@dataclass
class JointSpec:
    name: str
    type: str  # revolute, continuous, fixed
    parent: str
    child: str
    xyz: np.ndarray
    rpy: np.ndarray
    axis: np.ndarray | None = None
    lower: float | None = None
    upper: float | None = None

    def xml(self) -> str:
        s = (f'  <joint name="{self.name}" type="{self.type}">\n'
             f'    <parent link="{self.parent}"/>\n    <child link="{self.child}"/>\n'
             f'    <origin xyz="{_v(self.xyz)}" rpy="{_v(self.rpy)}"/>\n')
        if self.axis is not None:
            s += f'    <axis xyz="{_v(self.axis)}"/>\n'
        if self.type in ("revolute", "prismatic"):
            s += f'    <limit lower="{_f(self.lower)}" upper="{_f(self.upper)}" effort="100.0" velocity="2.0"/>\n'
        return s + "  </joint>\n"


def urdf_text(robot: str, links: list[LinkSpec], joints: list[JointSpec]) -> str:
    body = "".join(lk.xml() for lk in links) + "".join(j.xml() for j in joints)
    return f'<?xml version="1.0"?>\n<robot name="{robot}">\n{body}</robot>\n'


@dataclass
class RandomArm:
    """A random arm + vehicle: the URDF text, the system-file text, and the truth they were written from."""

    n_joints: int
    links: list[LinkSpec]
    joints: list[JointSpec]  # in URDF order, fixed ones included
    base_link: str
    tool_link: str
    mount_xyz: np.ndarray
    mount_rpy: np.ndarray
    q_stow: np.ndarray
    qmin: np.ndarray  # -inf / inf for continuous joints
    qmax: np.ndarray
    vehicle_mass: float
    vehicle_inertia_origin: np.ndarray  # 3x3 tensor about the body origin (positive definite)
    vehicle_com: np.ndarray
    vehicle_volume: float
    vehicle_cob: np.ndarray
    payload_mass: float
    payload_volume: float
    hydro_links: dict = field(default_factory=dict)  # link -> dict(volume, cob, drag_diameter, drag_from, drag_to)
    thrusters: list = field(default_factory=list)  # (position, direction, u_min, u_max)
    vehicle_hydro: dict = field(default_factory=dict)  # SI derivative name -> value
    system_name: str = "urdf_arm"
    urdf_name: str = "arm.urdf"

    @property
    def urdf(self) -> str:
        return urdf_text(f"random_arm_{self.n_joints}", self.links, self.joints)

    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints if j.type in ("revolute", "continuous")]

    @property
    def toml(self) -> str:
        return self.system_toml()

    def system_toml(self) -> str:
        lines = [
            "# written by tests/urdf_arms.py: a random vehicle and a random URDF arm (docs/system-file.md form 3)",
            "[system]",
            f'name = "{self.system_name}"',
            f'description = "random test arm of {self.n_joints} revolute joints"',
            "",
            "[env]",
            f"rho = {_entry(1025.0, 'kg/m^3')}",
            f"g = {_entry(9.81, 'm/s^2')}",
            f"Cd = {_entry(1.0, '1')}",
            "",
            "[vehicle]",
            f"m = {_entry(self.vehicle_mass, 'kg')}",
            f"volume = {_entry(self.vehicle_volume, 'm^3')}",
        ]
        I = self.vehicle_inertia_origin
        # Fossen's sign convention: the tensor has -Ixy off the diagonal
        for k, v in (("Ixx", I[0, 0]), ("Iyy", I[1, 1]), ("Izz", I[2, 2]),
                     ("Ixy", -I[0, 1]), ("Iyz", -I[1, 2]), ("Ixz", -I[0, 2])):
            lines.append(f"{k} = {_entry(v, 'kg*m^2')}")
        for k, v in zip(("xG", "yG", "zG", "xB", "yB", "zB"), np.concatenate([self.vehicle_com, self.vehicle_cob])):
            lines.append(f"{k} = {_entry(v, 'm')}")
        lines += ["", "[hydro]"]
        for k, v in self.vehicle_hydro.items():
            lines.append(f"{k} = {_entry(v, 'SI')}")
        for i, (pos, d, umin, umax) in enumerate(self.thrusters, start=1):
            lines += ["", "[[thrusters.unit]]", f'name = "T{i}"', f"position = {_entry(pos, 'm')}",
                      f"direction = {_entry(d, '1')}", f"u_min = {_entry(umin, 'N')}", f"u_max = {_entry(umax, 'N')}"]
        if self.n_joints == 0:  # the vehicle alone: no [arm], no [payload] (docs/system-file.md)
            return "\n".join(lines + [""])
        lines += ["", "[arm]", f'urdf = "{self.urdf_name}"', f'base_link = "{self.base_link}"',
                  f'tool_link = "{self.tool_link}"', "", "[arm.mount]"]
        for k, v in zip(("x", "y", "z"), self.mount_xyz):
            lines.append(f"{k} = {_entry(v, 'm')}")
        for k, v in zip(("roll", "pitch", "yaw"), self.mount_rpy):
            lines.append(f"{k} = {_entry(v, 'rad')}")
        lines += ["", "[arm.stow]"]
        for i, v in enumerate(self.q_stow, start=1):
            lines.append(f"q{i} = {_entry(v, 'rad')}")
        for name, h in self.hydro_links.items():
            lines += ["", f"[arm.hydro.{name}]", f"volume = {_entry(h['volume'], 'm^3')}",
                      f"cob = {_entry(h['cob'], 'm')}", f"drag_diameter = {_entry(h['drag_diameter'], 'm')}",
                      f"drag_from = {_entry(h['drag_from'], 'm')}", f"drag_to = {_entry(h['drag_to'], 'm')}"]
        lines += ["", "[payload]", f"mass = {_entry(self.payload_mass, 'kg')}",
                  f"volume = {_entry(self.payload_volume, 'm^3')}", ""]
        return "\n".join(lines)

    def write(self, directory, toml_name: str = "system.toml") -> Path:
        """Write the URDF and the system file into ``directory``; returns the system file's path."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        if self.n_joints:
            (d / self.urdf_name).write_text(self.urdf)
        path = d / toml_name
        path.write_text(self.system_toml())
        return path


def _random_unit(rng) -> np.ndarray:
    while True:
        a = rng.normal(size=3)
        n = np.linalg.norm(a)
        if n > 0.1 and np.abs(a / n).max() < 0.98:  # not (nearly) a coordinate axis
            return a / n


def _random_inertial(rng, name: str, mass_range=(0.3, 5.0)) -> LinkSpec:
    m = rng.uniform(*mass_range)
    return LinkSpec(name, m, rng.uniform(-0.15, 0.15, 3), rng.uniform(-np.pi, np.pi, 3),
                    realisable_inertia(rng, 0.002 + 0.01 * m))


def _thruster_layout(rng):
    """BlueROV2-Heavy-like: 4 vectored horizontal + 4 vertical thrusters, perturbed; rank 6 checked."""
    while True:
        units = []
        for sx in (1, -1):
            for sy in (1, -1):
                pos = np.array([0.15 * sx, 0.11 * sy, 0.0]) + rng.uniform(-0.02, 0.02, 3)
                ang = np.arctan2(-sy, sx) + rng.uniform(-0.2, 0.2)
                d = np.array([np.cos(ang), np.sin(ang), rng.uniform(-0.1, 0.1)])
                units.append((pos, d / np.linalg.norm(d), -40.0, 50.0))
        for sx in (1, -1):
            for sy in (1, -1):
                pos = np.array([0.12 * sx, 0.22 * sy, -0.005]) + rng.uniform(-0.02, 0.02, 3)
                d = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), 1.0])
                units.append((pos, d / np.linalg.norm(d), -40.0, 50.0))
        B = np.column_stack([np.concatenate([d, np.cross(p, d)]) for p, d, _, _ in units])
        s = np.linalg.svd(B, compute_uv=False)
        if s[-1] > 1e-2 * s[0]:
            return units


def random_arm(rng, n_joints: int, *, fixed_joint: bool = False, continuous: bool = False,
               tool_link: bool = True, system_name: str | None = None, urdf_name: str = "arm.urdf") -> RandomArm:
    """A random serial arm of ``n_joints`` revolute joints (0..7 for a valid arm; more for bad-input tests;
    0: the vehicle alone, its system file without ``[arm]`` and ``[payload]``).

    Joint origins: xyz in [-0.3, 0.3] m, random rpy; random unit axes, never a coordinate axis; limits
    [lower, upper] with lower < 0 < upper; moving links with random mass, com offset, inertial frame and
    full realisable inertia tensor. ``fixed_joint``: a fixed joint (with a massive flange link, merged
    into its parent) between joints 1 and 2 (or after joint 1 if n = 1); ``continuous``: the last joint
    is ``continuous``; ``tool_link``: a massless tool link on a fixed joint at the end (else the tool
    point is the last link's origin). The vehicle: mass, volume, full positive-definite inertia about the
    body origin, CG/CB offsets, a few SI hydrodynamic terms, 8 thrusters of rank 6.
    """
    links = [LinkSpec("base_link")]
    joints: list[JointSpec] = []
    qmin, qmax = [], []
    parent = "base_link"
    for i in range(1, n_joints + 1):
        cont = continuous and i == n_joints
        lo, hi = (None, None) if cont else (rng.uniform(-np.pi, -0.2), rng.uniform(0.2, np.pi))
        xyz = rng.uniform(-0.3, 0.3, 3)
        rpy = np.array([rng.uniform(-np.pi, np.pi), rng.uniform(-1.5, 1.5), rng.uniform(-np.pi, np.pi)])
        joints.append(JointSpec(f"joint{i}", "continuous" if cont else "revolute", parent, f"link{i}",
                                xyz, rpy, _random_unit(rng), lo, hi))
        links.append(_random_inertial(rng, f"link{i}"))
        qmin.append(-np.inf if cont else lo)
        qmax.append(np.inf if cont else hi)
        parent = f"link{i}"
        if fixed_joint and i == 1:
            joints.append(JointSpec("flange1", "fixed", parent, "flange1_link", rng.uniform(-0.2, 0.2, 3),
                                    rng.uniform(-np.pi, np.pi, 3)))
            links.append(_random_inertial(rng, "flange1_link", (0.1, 1.0)))
            parent = "flange1_link"
    tool = parent
    if tool_link:
        joints.append(JointSpec("tool_joint", "fixed", parent, "tool_link", rng.uniform(-0.2, 0.2, 3),
                                rng.uniform(-np.pi, np.pi, 3)))
        links.append(LinkSpec("tool_link"))
        tool = "tool_link"
    qmin, qmax = np.array(qmin), np.array(qmax)
    q_stow = np.array([rng.uniform(0.5 * lo, 0.5 * hi) if np.isfinite(lo) else rng.uniform(-1, 1)
                       for lo, hi in zip(qmin, qmax)])

    # vehicle: realisable inertia about its CG, moved to the body origin (parallel axis)
    m = rng.uniform(10.0, 40.0)
    rG = rng.uniform(-0.03, 0.03, 3)
    I_c = realisable_inertia(rng, 0.02 * m)
    I_o = I_c + m * (rG @ rG * np.eye(3) - np.outer(rG, rG))
    rB = rng.uniform(-0.03, 0.03, 3)
    vol = m / 1025.0 * rng.uniform(1.0, 1.05)
    hydro = {"X_u": -rng.uniform(1, 10), "Y_v": -rng.uniform(1, 10), "Z_w": -rng.uniform(1, 10),
             "K_p": -rng.uniform(0.1, 1), "M_q": -rng.uniform(0.1, 1), "N_r": -rng.uniform(0.1, 1),
             "X_u_absu": -rng.uniform(10, 40), "Z_w_absw": -rng.uniform(10, 40),
             "X_udot": -rng.uniform(1, 5), "Y_vdot": -rng.uniform(1, 5), "Z_wdot": -rng.uniform(1, 5),
             "K_pdot": -rng.uniform(0.01, 0.1), "M_qdot": -rng.uniform(0.01, 0.1), "N_rdot": -rng.uniform(0.01, 0.1)}

    # per moving link: buoyancy and a drag segment from its origin to the next joint (or the tool)
    by_name = {lk.name: lk for lk in links}
    hydro_links = {}
    for i in range(1, n_joints + 1):
        lk = by_name[f"link{i}"]
        nxt = next((j for j in joints if j.parent == lk.name), None)
        to = nxt.xyz if nxt is not None and np.linalg.norm(nxt.xyz) > 0.02 else np.array([0.0, 0.0, 0.1])
        hydro_links[lk.name] = dict(volume=lk.mass / rng.uniform(2000, 4000), cob=lk.com + rng.uniform(-0.01, 0.01, 3),
                                    drag_diameter=rng.uniform(0.03, 0.12), drag_from=np.zeros(3), drag_to=to)
    return RandomArm(
        n_joints=n_joints, links=links, joints=joints, base_link="base_link", tool_link=tool,
        mount_xyz=rng.uniform(-0.4, 0.4, 3), mount_rpy=rng.uniform(-np.pi, np.pi, 3) * np.array([1, 0.45, 1]),
        q_stow=q_stow, qmin=qmin, qmax=qmax, vehicle_mass=m, vehicle_inertia_origin=I_o, vehicle_com=rG,
        vehicle_volume=vol, vehicle_cob=rB, payload_mass=rng.uniform(0.3, 2.0), payload_volume=rng.uniform(1e-4, 8e-4),
        hydro_links=hydro_links, thrusters=_thruster_layout(rng), vehicle_hydro=hydro,
        system_name=system_name or f"urdf_arm_{n_joints}", urdf_name=urdf_name)


# The random arms of the tests: every size 1..7, each plain and with a fixed flange joint (merged), a
# continuous last joint and (even sizes) a tool link on a fixed joint. Same (n, variant), same arm.
ARM_CASES = [(n, v) for n in range(1, 8) for v in ("plain", "fixed_continuous")]


def case_arm(n: int, variant: str, seed: int = 0) -> RandomArm:
    rng = np.random.default_rng(1000 * n + seed + (500 if variant != "plain" else 0))
    if variant == "plain":
        return random_arm(rng, n)
    return random_arm(rng, n, fixed_joint=True, continuous=True, tool_link=(n % 2 == 0))


def bad_urdf(arm: RandomArm, fault: str) -> RandomArm:
    """A copy of ``arm`` with one fault: ``prismatic`` (joint2 made prismatic), ``no_inertial`` (link2 has
    none), ``not_pd`` (link2's tensor indefinite: eigenvalues -0.05, 0.25, 0.1 kg m^2)."""
    import copy

    a = copy.deepcopy(arm)
    j = next(j for j in a.joints if j.name == "joint2")
    lk = next(lk for lk in a.links if lk.name == "link2")
    if fault == "prismatic":
        j.type = "prismatic"
        j.lower, j.upper = -0.1, 0.1
    elif fault == "no_inertial":
        lk.mass = None
    elif fault == "not_pd":
        lk.inertia_local = np.array([[0.1, 0.15, 0.0], [0.15, 0.1, 0.0], [0.0, 0.0, 0.1]])
    else:
        raise ValueError(fault)
    return a


# ---------------------------------------------------------------------------------------------
# Haidou-1 from its modified-DH table


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _cylinder_inertia(mass: float, diameter: float, s: np.ndarray) -> np.ndarray:
    """Solid cylinder along s, about its centre (tests/pinocchio_model.py's formula)."""
    from pinocchio_model import cylinder_inertia

    return cylinder_inertia(mass, diameter, s)


def haidou1_link_vectors(params, n: int = 6) -> list[np.ndarray]:
    """s_i = P^i_{i+1} (the next joint's origin in frame {i}); s_n = the tool point [0, 0, L_tool]."""
    s = []
    for i in range(2, n + 1):
        a, d, al = params[f"arm.joint{i}.a"], params[f"arm.joint{i}.d"], params[f"arm.joint{i}.alpha"]
        s.append(np.array([a, 0.0, 0.0]) + _rot_x(al) @ np.array([0.0, 0.0, d]))
    s.append(np.array([0.0, 0.0, params["arm.tool.length"]]))
    return s


def haidou1_urdf(params, n: int = 6) -> str:
    """Haidou-1's arm as URDF from its DH table and cylinder links (``params``: SI values by name).

    base_link = DH frame {0}; joint i: xyz = [a, -sin(alpha) d, cos(alpha) d], rpy = [alpha, 0, 0], axis
    z; link i = DH frame {i}, its inertial the solid cylinder from its origin to s_i (centre of mass at
    s_i / 2, tensor in the link frame); tool_link on a fixed joint at [0, 0, L_tool] in link n.
    """
    s = haidou1_link_vectors(params, n)
    links = [LinkSpec("base_link")]
    joints = []
    parent = "base_link"
    for i in range(1, n + 1):
        a, d, al = params[f"arm.joint{i}.a"], params[f"arm.joint{i}.d"], params[f"arm.joint{i}.alpha"]
        xyz = np.array([a, 0.0, 0.0]) + _rot_x(al) @ np.array([0.0, 0.0, d])
        joints.append(JointSpec(f"joint{i}", "revolute", parent, f"link{i}", xyz, np.array([al, 0.0, 0.0]),
                                np.array([0.0, 0.0, 1.0]), params[f"arm.joint{i}.qmin"], params[f"arm.joint{i}.qmax"]))
        m = params[f"arm.link{i}.mass"]
        links.append(LinkSpec(f"link{i}", m, 0.5 * s[i - 1], np.zeros(3),
                              _cylinder_inertia(m, params[f"arm.link{i}.diameter"], s[i - 1])))
        parent = f"link{i}"
    joints.append(JointSpec("tool_joint", "fixed", parent, "tool_link", s[-1], np.zeros(3)))
    links.append(LinkSpec("tool_link"))
    return urdf_text("haidou1_arm", links, joints)


def haidou1_hydro_toml(params, n: int = 6) -> str:
    """The ``[arm.hydro.link<i>]`` sections equal to the DH form's cylinders: volume, COB at the middle,
    drag over the whole link (origin {i} to origin {i+1}) with the link's diameter."""
    s = haidou1_link_vectors(params, n)
    src = "tests/urdf_arms.py: Haidou-1's DH link written as form 3"
    out = []
    for i in range(1, n + 1):
        out += [f"[arm.hydro.link{i}]",
                f"volume = {_entry(params[f'arm.link{i}.volume'], 'm^3', src)}",
                f"cob = {_entry(0.5 * s[i - 1], 'm', src)}",
                f"drag_diameter = {_entry(params[f'arm.link{i}.diameter'], 'm', src)}",
                f"drag_from = {_entry(np.zeros(3), 'm', src)}",
                f"drag_to = {_entry(s[i - 1], 'm', src)}", ""]
    return "\n".join(out)


_SECTION = re.compile(r"^\s*\[{1,2}\s*([A-Za-z0-9_.\-\"]+)\s*\]{1,2}\s*(#.*)?$")
_DROP = re.compile(r"^arm(\.joint\d+|\.link\d+|\.tool)?$")


def shipped_haidou1_text() -> str:
    """The text of the packaged Haidou-1 system file (wherever under arvcas/ it lives: the DH form)."""
    from importlib import resources

    root = Path(str(resources.files("arvcas")))
    found = sorted(root.rglob("haidou1.toml"), key=lambda p: (len(p.parts), str(p)))
    for p in found:
        text = p.read_text()
        if "[arm.joint1]" in text:
            return text
    raise FileNotFoundError(f"no haidou1.toml with an [arm.joint1] section under {root}")


def haidou1_form3_toml(shipped_text: str, params, urdf_name: str = "haidou1_arm.urdf",
                       system_name: str = "haidou1_urdf", n: int = 6) -> str:
    """Haidou-1's system file with its arm in form 3: the shipped text with ``[arm]``,
    ``[arm.joint<i>]``, ``[arm.link<i>]`` and ``[arm.tool]`` removed and replaced by ``[arm] urdf``
    (+ base_link, tool_link) and the ``[arm.hydro.link<i>]`` cylinders; every other section (vehicle,
    hydro, thrusters, mount, stow, payload) is kept as written. ``[system] name`` is renamed (or the
    section added) so the two forms never share compiled code by name."""
    out, keep, seen_system = [], True, False
    for line in shipped_text.splitlines():
        m = _SECTION.match(line)
        if m:
            name = m.group(1).replace('"', "")
            keep = not _DROP.match(name)
            if name == "system":
                seen_system = True
        if not keep:
            continue
        if re.match(r"^\s*name\s*=", line) and _in_system(out):
            line = f'name = "{system_name}"'
        out.append(line)
    text = "\n".join(out) + "\n"
    if not seen_system:
        text = (f'[system]\nname = "{system_name}"\ndescription = "Haidou-1, its arm as URDF (tests)"\n\n'
                + text)
    text += ("\n[arm]\n"
             f'urdf = "{urdf_name}"\nbase_link = "base_link"\ntool_link = "tool_link"\n\n'
             + haidou1_hydro_toml(params, n))
    return text


def _in_system(out: list[str]) -> bool:
    """Whether the last section header in ``out`` is ``[system]``."""
    for line in reversed(out):
        m = _SECTION.match(line)
        if m:
            return m.group(1) == "system"
    return False
