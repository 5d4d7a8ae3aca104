"""A revolute arm of 0-7 joints: kinematics and recursive Newton-Euler on a moving base.

Paper eq. 7-11 with docs/model.md §3, for the two arm forms of docs/system-file.md:

* modified DH (Haidou-1's Table 1): link i spans origin {i} -> origin {i+1} (the last: ``[0, 0, L_tool]``
  along z_n), centre of mass and of buoyancy at the middle of each link, solid-cylinder inertia;
* chain (URDF semantics): joint origins and axes, link mass, centre of mass, full inertia tensor,
  volume and centre of buoyancy, and a drag cylinder on a segment of each link.

Both have per-link buoyancy and quadrature drag and a point payload at the tool point. The base is the
vehicle: frame {0} sits at ``P^b_0`` in {b}, rotated by ``R^b_0`` (identity for Haidou-1).

Sign convention: :func:`arm_wrench` returns ``tau_m``, the wrench the arm exerts *on the vehicle*,
in {b} about the COB (at rest and level its z force is the arm's weight in water, positive down).
"""

from __future__ import annotations

import casadi as ca

from arvcas.model import hydro
from arvcas.model.spatial import Rx, Rz, Rzyx, skew

__all__ = [
    "n_joints", "dh", "joint_axis", "link_vectors", "link_inertia", "forward_kinematics", "rnea", "arm_wrench",
    "stow_pose", "has_trim", "trim_wrench", "trim_static", "trim_from_static", "base_inertia", "mount", "tool_point",
    "drag_links", "drag_segment", "schedule_fields", "arm_schedule", "drag_wrench", "arm_wrench_scheduled",
]

_Z = ca.DM([0, 0, 1])


def n_joints(P) -> int:
    return P.s.n_joints


def _vec(P, key):
    return ca.vertcat(*[P[f"{key}.{c}"] for c in "xyz"])


def joint_axis(P, i: int):
    """Unit axis of joint i in its own frame: z for a DH joint, the file's axis for a chain joint."""
    return _Z if P.s.arm == "dh" else _vec(P, f"arm.joint{i}.axis")


def _rot_axis(k, q):
    """Rotation by q about the unit vector k (Rodrigues)."""
    K = skew(k)
    return ca.DM.eye(3) + ca.sin(q) * K + (1 - ca.cos(q)) * ca.mtimes(K, K)


def dh(P, i: int, q_i):
    """Transform of joint i (1-based) at angle q_i: (R^{i-1}_i, p^{i-1}_i).

    Modified DH: T_{i-1,i} = RotX(alpha) TransX(a) RotZ(q) TransZ(d). Chain (URDF semantics):
    Trans(xyz) Rot(rpy) Rot(axis, q), with R(rpy) = Rz(yaw) Ry(pitch) Rx(roll).
    """
    if P.s.arm == "dh":
        a, d, al = P[f"arm.joint{i}.a"], P[f"arm.joint{i}.d"], P[f"arm.joint{i}.alpha"]
        R = ca.mtimes(Rx(al), Rz(q_i))
        p = ca.vertcat(a, -ca.sin(al) * d, ca.cos(al) * d)
        return R, p
    J_ = f"arm.joint{i}"
    R0 = Rzyx(P[J_ + ".roll"], P[J_ + ".pitch"], P[J_ + ".yaw"])
    return ca.mtimes(R0, _rot_axis(joint_axis(P, i), q_i)), ca.vertcat(P[J_ + ".x"], P[J_ + ".y"], P[J_ + ".z"])


def link_vectors(P):
    """DH arms: s_i = P^i_{i+1} for links 1..n (docs/model.md §3); s_n reaches the tool point along z_n."""
    n = n_joints(P)
    s = []
    for i in range(1, n):
        a, al, d = P[f"arm.joint{i + 1}.a"], P[f"arm.joint{i + 1}.alpha"], P[f"arm.joint{i + 1}.d"]
        s.append(ca.vertcat(a, -ca.sin(al) * d, ca.cos(al) * d))
    s.append(ca.vertcat(0, 0, P["arm.tool.length"]))
    return s


def link_inertia(mass, diameter, s):
    """Inertia about the centre of mass of a solid cylinder along ``s``, in the link frame."""
    L2 = ca.dot(s, s)
    uu = ca.mtimes(s, s.T) / L2
    r2 = (0.5 * diameter) ** 2
    I_ax = 0.5 * mass * r2
    I_tr = mass * (3 * r2 + L2) / 12.0
    return I_tr * (ca.DM.eye(3) - uu) + I_ax * uu


def _chain_inertia(P, i: int):
    k = f"arm.link{i}.inertia."
    ixx, iyy, izz, ixy, ixz, iyz = (P[k + e] for e in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz"))
    return ca.vertcat(ca.horzcat(ixx, ixy, ixz), ca.horzcat(ixy, iyy, iyz), ca.horzcat(ixz, iyz, izz))


def drag_links(P) -> list[int]:
    """The links that meet the flow: every DH link; chain links with a drag segment."""
    n = n_joints(P)
    if P.s.arm == "dh":
        return list(range(1, n + 1))
    return [i for i in range(1, n + 1) if P.s.link_drag[i - 1]]


def drag_segment(P, i: int, s_list=None):
    """(start r0, vector s, diameter D, Cd) of link i's drag cylinder, in its frame."""
    if P.s.arm == "dh":
        s = (s_list or link_vectors(P))[i - 1]
        return None, s, P[f"arm.link{i}.diameter"], P["env.Cd"]
    r0 = _vec(P, f"arm.link{i}.drag_from")
    s = _vec(P, f"arm.link{i}.drag_to") - r0
    cd = P[f"arm.link{i}.Cd"] if P.s.link_cd[i - 1] else P["env.Cd"]
    return r0, s, P[f"arm.link{i}.drag_diameter"], cd


def tool_point(P):
    """The tool point (payload) in the last link's frame."""
    if P.s.arm == "dh":
        return ca.vertcat(0, 0, P["arm.tool.length"])
    return ca.vertcat(P["arm.tool.x"], P["arm.tool.y"], P["arm.tool.z"])


def mount(P):
    """(p^b_0, R^b_0): the arm's base frame in the body frame (R None: identity, Haidou-1)."""
    pb0 = ca.vertcat(P["arm.mount.x"], P["arm.mount.y"], P["arm.mount.z"])
    R = Rzyx(P["arm.mount.roll"], P["arm.mount.pitch"], P["arm.mount.yaw"]) if P.s.mount_rpy else None
    return pb0, R


def forward_kinematics(P, q):
    """Pose of frames {1..n} in {0}: list of (R^0_i, p^0_i)."""
    R, p = ca.DM.eye(3), ca.DM.zeros(3)
    out = []
    for i in range(1, n_joints(P) + 1):
        Ri, pi = dh(P, i, q[i - 1])
        p = p + ca.mtimes(R, pi)
        R = ca.mtimes(R, Ri)
        out.append((R, p))
    return out


def _kinematics_b(P, q):
    """Pose of frames {1..n} in {b}: (R^b_i, p^b_i)."""
    pb0, Rb0 = mount(P)
    if Rb0 is None:
        return [(R, pb0 + p) for R, p in forward_kinematics(P, q)]
    return [(ca.mtimes(Rb0, R), pb0 + ca.mtimes(Rb0, p)) for R, p in forward_kinematics(P, q)]


def rnea(P, q, qd, qdd, w0, wd0, v0, a0, g0, payload, n_quad: int = 5, drag: bool = True):
    """Recursive Newton-Euler (paper eq. 7, 8, 10) on a base frame {0} moving with (w0, wd0, v0, a0).

    All base quantities are in {0}: angular velocity/acceleration, velocity and absolute acceleration of
    the origin, gravity vector ``g0`` (m/s^2); ``drag=False`` leaves the fluid drag out. Returns (f_1, n_1, R^0_1, p^0_1): the force and moment the
    base exerts on link 1 at origin {1}, in frame {1}.
    """
    rho = P["env.rho"]
    n = n_joints(P)
    is_dh = P.s.arm == "dh"
    s_list = link_vectors(P) if is_dh else None
    w, wd, v, a, g = w0, wd0, v0, a0, g0
    frames = []
    kin = []
    for i in range(1, n + 1):
        Ri, pi = dh(P, i, q[i - 1])
        RiT = Ri.T
        z = joint_axis(P, i)
        # eq. 7: propagate to frame i (quantities of frame i-1 first moved by p_i)
        a = ca.mtimes(RiT, a + ca.cross(wd, pi) + ca.cross(w, ca.cross(w, pi)))
        v = ca.mtimes(RiT, v + ca.cross(w, pi))
        w_prev = ca.mtimes(RiT, w)
        w = w_prev + qd[i - 1] * z
        wd = ca.mtimes(RiT, wd) + ca.cross(w_prev, qd[i - 1] * z) + qdd[i - 1] * z
        g = ca.mtimes(RiT, g)
        frames.append((Ri, pi))
        kin.append((w, wd, v, a, g))

    f_next, n_next = ca.DM.zeros(3), ca.DM.zeros(3)
    dragged = set(drag_links(P)) if drag else set()
    for i in range(n, 0, -1):
        w, wd, v, a, g = kin[i - 1]
        m_i = P[f"arm.link{i}.mass"]
        V_i = P[f"arm.link{i}.volume"]
        if is_dh:
            s = s_list[i - 1]
            c = 0.5 * s  # COM = COB at the middle of the link (docs/model.md §3)
            Ic = link_inertia(m_i, P[f"arm.link{i}.diameter"], s)
        else:
            c = _vec(P, f"arm.link{i}.com")
            Ic = _chain_inertia(P, i)
        a_c = a + ca.cross(wd, c) + ca.cross(w, ca.cross(w, c))
        F = m_i * a_c  # eq. 8
        N = ca.mtimes(Ic, wd) + ca.cross(w, ca.mtimes(Ic, w))
        if i in dragged:
            r0, sd, D_i, Cd = drag_segment(P, i, s_list)
            if r0 is None:
                f_d, n_d = hydro.link_drag(rho, Cd, D_i, sd, v, w, n_quad)
            else:  # the segment starts at r0: its velocity there, its moment moved to the origin
                f_d, n_d = hydro.link_drag(rho, Cd, D_i, sd, v + ca.cross(w, r0), w, n_quad)
                n_d = n_d + ca.cross(r0, f_d)
        else:
            f_d, n_d = 0, 0
        if i < n:
            R_next, p_next = frames[i]
            f_child = ca.mtimes(R_next, f_next)
            n_child = ca.mtimes(R_next, n_next) + ca.cross(p_next, f_child)
        else:
            # payload: point mass at the tool point, scaled by payload in [0, 1] (docs/model.md §3)
            t = s if is_dh else tool_point(P)
            a_t = a + ca.cross(wd, t) + ca.cross(w, ca.cross(w, t))
            mp, Vp = P["payload.mass"], P["payload.volume"]
            f_child = payload * (mp * a_t - mp * g - hydro.buoyancy_force(rho, Vp, g))
            n_child = ca.cross(t, f_child)
        # eq. 10 with explicit external loads: what the parent must supply
        if is_dh:
            ext_c = m_i * g + hydro.buoyancy_force(rho, V_i, g)  # weight + buoyancy, both at c
            f_next = f_child + F - ext_c - f_d
            n_next = n_child + N + ca.cross(c, F - ext_c) - n_d
        else:
            f_b = hydro.buoyancy_force(rho, V_i, g)
            cb = _vec(P, f"arm.link{i}.cob")
            f_next = f_child + F - m_i * g - f_b - f_d
            n_next = n_child + N + ca.cross(c, F - m_i * g) - ca.cross(cb, f_b) - n_d
    R1, p1 = frames[0]
    return f_next, n_next, R1, p1


def _base_motion(P, nu, nud):
    """(w0, wd0, v0, a0) of the arm's base frame {0}, in {0}, from the vehicle's nu and nu_dot."""
    pb0, Rb0 = mount(P)
    v_b, w_b = nu[0:3], nu[3:6]
    a_b = nud[0:3] + ca.cross(w_b, v_b)  # absolute acceleration of the COB, in {b}
    wd_b = nud[3:6]
    w0, wd0 = w_b, wd_b
    v0 = v_b + ca.cross(w_b, pb0)
    a0 = a_b + ca.cross(wd_b, pb0) + ca.cross(w_b, ca.cross(w_b, pb0))
    if Rb0 is None:  # R^b_0 = I (docs/model.md §3)
        return w0, wd0, v0, a0
    RT = Rb0.T
    return ca.mtimes(RT, w0), ca.mtimes(RT, wd0), ca.mtimes(RT, v0), ca.mtimes(RT, a0)


def arm_wrench(P, eta, nu, nud, q, qd, qdd, payload, n_quad: int = 5, v_c_b=None):
    """tau_m of eq. 11: the arm's wrench on the vehicle in {b} about the COB (docs/model.md §3 sign).

    ``nud`` is Fossen's nu_dot (time derivative of the body-frame velocity components). Zero for a
    system without an arm. ``v_c_b``: the current's velocity in {b} (docs/model.md §10): the links' drag
    acts on the flow relative to the water.
    """
    if n_joints(P) == 0:
        return ca.DM.zeros(6)
    w0, wd0, v0, a0 = _base_motion(P, nu, nud)
    if v_c_b is not None:  # only the drag reads v: the water's velocity comes off every point's velocity
        _, Rb0 = mount(P)
        v0 = v0 - (v_c_b if Rb0 is None else ca.mtimes(Rb0.T, v_c_b))
    R = Rzyx(eta[3], eta[4], eta[5])
    g0 = ca.mtimes(R.T, ca.vertcat(0, 0, P["env.g"]))
    _, Rb0 = mount(P)
    if Rb0 is not None:
        g0 = ca.mtimes(Rb0.T, g0)
    f1, n1, R1, p1 = rnea(P, q, qd, qdd, w0, wd0, v0, a0, g0, payload, n_quad)
    return -_to_cob(P, f1, n1, R1, p1)


def _bodies(P, q, payload):
    """The arm's bodies in {b}: links 1..n and the payload point mass at the tool point.

    Each entry: ``m`` (mass), ``m_wet`` (mass minus displaced water), ``wet_first`` (first moment of
    weight minus buoyancy per g, about the COB), ``c`` (centre of mass in {b}), ``r`` (centre from the
    origin of its link's frame, in {b}), the rotational inertia about ``c``: for a DH cylinder as
    ``I_tr I + k_ax Rs Rs'`` (``Rs``: the link vector in {b}), for a chain link as ``Ic`` (3x3 in {b}),
    ``None`` and zeros for the payload; and ``link`` (the link the body rides on).
    """
    rho = P["env.rho"]
    n = n_joints(P)
    is_dh = P.s.arm == "dh"
    s_list = link_vectors(P) if is_dh else None
    out = []
    for i, (R, p) in enumerate(_kinematics_b(P, q), start=1):
        m_i = P[f"arm.link{i}.mass"]
        if is_dh:
            s = s_list[i - 1]
            L2 = ca.dot(s, s)
            r2 = (0.5 * P[f"arm.link{i}.diameter"]) ** 2
            I_ax = 0.5 * m_i * r2
            I_tr = m_i * (3 * r2 + L2) / 12.0
            Rs = ca.mtimes(R, s)
            m_wet = m_i - rho * P[f"arm.link{i}.volume"]
            c = p + 0.5 * Rs
            out.append(dict(m=m_i, m_wet=m_wet, wet_first=m_wet * c, c=c, r=0.5 * Rs,
                            I_tr=I_tr, k_ax=(I_ax - I_tr) / L2, Rs=Rs, Ic=None, link=i))
            t_b = Rs
        else:
            r = ca.mtimes(R, _vec(P, f"arm.link{i}.com"))
            c = p + r
            V = P[f"arm.link{i}.volume"]
            cb = p + ca.mtimes(R, _vec(P, f"arm.link{i}.cob"))
            Ic = ca.mtimes(R, ca.mtimes(_chain_inertia(P, i), R.T))
            out.append(dict(m=m_i, m_wet=m_i - rho * V, wet_first=m_i * c - rho * V * cb, c=c, r=r,
                            I_tr=0, k_ax=0, Rs=None, Ic=Ic, link=i))
            t_b = ca.mtimes(R, tool_point(P))
        if i == n:
            mp = P["payload.mass"]
            m_wet = payload * (mp - rho * P["payload.volume"])
            c = p + t_b
            out.append(dict(m=payload * mp, m_wet=m_wet, wet_first=m_wet * c, c=c, r=t_b,
                            I_tr=0, k_ax=0, Rs=None, Ic=None, link=i))
    return out


def _spatial_inertia(mass, first, J):
    """[[m I, -S(sum m c)], [S(sum m c), J]] about the COB from the mass, first moment and rotational inertia."""
    S1 = skew(first)
    return ca.vertcat(
        ca.horzcat(mass * ca.DM.eye(3), -S1),
        ca.horzcat(S1, J),
    )


def base_inertia(P, q, payload):
    """Composite spatial inertia of the arm (+ payload) about the COB in {b}: M_arm(q).

    The arm's wrench on the vehicle is affine in the vehicle acceleration,
    ``tau_m = tau_m(nu_dot = 0) - M_arm(q) nu_dot`` (exact), and the coupled vehicle solves
    ``(M + M_arm) nu_dot = ...`` (docs/model.md §3). Each body with mass m, centre c (in {b}) and inertia I_c
    about c contributes ``[[m I, -m S(c)], [m S(c), I_c - m S(c) S(c)]]``; summed through the first
    moment ``sum m c`` and ``-sum m S(c)^2 = sum m (|c|^2 I - c c')``. A link's cylinder inertia is
    ``I_c = I_tr I + (I_ax - I_tr) w w'`` with ``w`` its unit axis in {b}.
    """
    if n_joints(P) == 0:
        return ca.DM.zeros(6, 6)
    mass = 0
    first = 0  # sum m c
    J = 0  # sum of rotational inertia about the COB (3x3 symmetric)
    for b in _bodies(P, q, payload):
        m, c = b["m"], b["c"]
        mass = mass + m
        mc = m * c
        first = first + mc
        J = J + (ca.dot(mc, c) + b["I_tr"]) * ca.DM.eye(3) - ca.mtimes(mc, c.T)
        if b["Rs"] is not None:
            J = J + b["k_ax"] * ca.mtimes(b["Rs"], b["Rs"].T)
        if b["Ic"] is not None:
            J = J + b["Ic"]
    return _spatial_inertia(mass, first, J)


# The time-only part of the arm's wrench: everything that depends on (q, qd, qdd, payload) and p but
# not on the vehicle state. (name, size); matrices are 6x6 symmetric, stored as their upper triangle.
# per link that meets the flow, in drag_frames: Omega (3), r (3), V (3), e1 (3), e2 (3); see arm_schedule
_DRAG_FRAME = 15


def schedule_fields(P) -> tuple[tuple[str, int], ...]:
    """(name, size) of the time-only terms of :func:`arm_schedule` for this system."""
    return (("M_arm", 21), ("M_arm_dot", 21), ("h_q", 6), ("b_q", 6), ("W", 1), ("S", 3),
            ("drag_frames", _DRAG_FRAME * len(drag_links(P))))


def arm_schedule(P, q, qd, qdd, payload) -> dict:
    """The vehicle-state-independent terms of the arm's wrench on the vehicle (docs/model.md §3, exact).

    With the arm's spatial momentum about the COB in {b}, ``h = M_arm(q) nu + h_q(q, qd)``, Newton-Euler
    for the arm in the moving body frame gives, at ``nu_dot = 0``,

        tau_m0 = [W g_b; S x g_b] + drag - (M_arm_dot nu + b_q + nu x* h)

    (``nu x* h = [w x h_lin; w x h_ang + v x h_lin]``, ``g_b = R(eta)' [0, 0, g]``). Returned here:

    - ``M_arm`` (:func:`base_inertia`) and ``M_arm_dot = dM_arm/dq qd``,
    - ``h_q``: the momentum of the joint motion alone (vehicle at rest),
    - ``b_q = d h_q / dt``: the fixed-base reaction, i.e. the recursive Newton-Euler of eq. 7-10 with the
      base at rest, no gravity and no drag,
    - ``W`` (kg): mass minus displaced water of the arm + payload, ``S`` (kg m): its first moment in {b},
    - ``drag_frames``: per link, in {b}, the angular velocity ``Omega`` of the joint motion, the origin
      ``r`` (from the COB) and its velocity ``V`` from the joint motion, and a basis ``e1, e2`` of the
      plane normal to the link (:func:`arvcas.model.hydro.normal_basis`): the drag's geometry
      (:func:`drag_wrench`).

    The payload fraction enters as a mass, not differentiated in time, like :func:`rnea`'s point mass.
    :func:`arm_wrench_scheduled` completes the wrench with the drag; together they equal
    :func:`arm_wrench` (tested to round-off). The closed loop tabulates these per time.
    """
    bodies = _bodies(P, q, payload)
    # velocities of the joint motion alone, in {b}: origin velocities and angular velocities
    pb0 = ca.vertcat(P["arm.mount.x"], P["arm.mount.y"], P["arm.mount.z"])
    pb0, Rb0 = mount(P)
    is_dh = P.s.arm == "dh"
    s_list = link_vectors(P) if is_dh else None
    dragged = set(drag_links(P))
    w = ca.DM.zeros(3)
    v_o = ca.DM.zeros(3)
    p_prev = ca.DM.zeros(3)
    link_w, link_vo = {}, {}
    frames = []
    for i, (R, p) in enumerate(forward_kinematics(P, q), start=1):
        dp = p - p_prev  # origin i is fixed in link i-1
        p_prev = p
        if Rb0 is not None:  # into {b}
            R, p, dp = ca.mtimes(Rb0, R), ca.mtimes(Rb0, p), ca.mtimes(Rb0, dp)
        v_o = v_o + ca.cross(w, dp)
        w = w + qd[i - 1] * ca.mtimes(R, joint_axis(P, i))
        link_w[i], link_vo[i] = w, v_o
        if i not in dragged:
            continue
        r0, s, _, _ = drag_segment(P, i, s_list)
        e1, e2 = hydro.normal_basis(s / ca.norm_2(s))
        if r0 is None:
            frames += [w, pb0 + p, v_o, ca.mtimes(R, e1), ca.mtimes(R, e2)]
        else:
            Rr0 = ca.mtimes(R, r0)
            frames += [w, pb0 + p + Rr0, v_o + ca.cross(w, Rr0), ca.mtimes(R, e1), ca.mtimes(R, e2)]
    h_lin, h_ang = 0, 0
    first_dot, J_dot = 0, 0
    W, S = 0, 0
    for b in bodies:
        m, c, w = b["m"], b["c"], link_w[b["link"]]
        c_dot = link_vo[b["link"]] + ca.cross(w, b["r"])
        mcd = m * c_dot
        h_lin = h_lin + mcd
        Iw = b["I_tr"] * w
        if b["Rs"] is not None:
            Iw = Iw + (b["k_ax"] * ca.dot(b["Rs"], w)) * b["Rs"]
        if b["Ic"] is not None:
            Iw = ca.mtimes(b["Ic"], w)
        h_ang = h_ang + Iw + ca.cross(c, mcd)
        # d/dt of m (|c|^2 I - c c') + k_ax Rs Rs', with d(Rs)/dt = w x Rs
        first_dot = first_dot + mcd
        mc = m * c
        J_dot = J_dot + (2 * ca.dot(mc, c_dot)) * ca.DM.eye(3) - ca.mtimes(mcd, c.T) - ca.mtimes(mc, c_dot.T)
        if b["Rs"] is not None:
            d = ca.cross(w, b["Rs"])
            J_dot = J_dot + b["k_ax"] * (ca.mtimes(d, b["Rs"].T) + ca.mtimes(b["Rs"], d.T))
        if b["Ic"] is not None:  # d/dt (R Ic R') = S(w) Ic_b - Ic_b S(w)
            Sw = skew(w)
            J_dot = J_dot + ca.mtimes(Sw, b["Ic"]) - ca.mtimes(b["Ic"], Sw)
        W = W + b["m_wet"]
        S = S + b["wet_first"]
    z3 = ca.DM.zeros(3)
    f1, n1, R1, p1 = rnea(P, q, qd, qdd, z3, z3, z3, z3, z3, payload, drag=False)
    return {
        "M_arm": base_inertia(P, q, payload),
        "M_arm_dot": _spatial_inertia(0, first_dot, J_dot),
        "h_q": ca.vertcat(h_lin, h_ang),
        "b_q": _to_cob(P, f1, n1, R1, p1),
        "W": W,
        "S": S,
        "drag_frames": ca.vertcat(*frames),
    }


def _to_cob(P, f1, n1, R1, p1):
    """A wrench at origin {1} in frame {1} moved to the COB in {b} (via {0}: p^b_0, R^b_0)."""
    pb0, Rb0 = mount(P)
    f0 = ca.mtimes(R1, f1)
    n0 = ca.mtimes(R1, n1) + ca.cross(p1, f0)
    if Rb0 is not None:
        f0, n0 = ca.mtimes(Rb0, f0), ca.mtimes(Rb0, n0)
    return ca.vertcat(f0, n0 + ca.cross(pb0, f0))


def drag_wrench(P, nu, frames, n_quad: int = 5, v_c_b=None):
    """The water's drag on the whole arm as a wrench at the COB in {b} (eq. 9 by quadrature, docs/model.md §3).

    Everything in {b}: link i turns at ``w_i = w + Omega_i`` and its origin moves at
    ``v + w x r_i + V_i`` (the vehicle's ``nu = [v; w]`` plus the joint motion); the normal velocity
    along the link, in the basis ``e1, e2``, is affine in x and integrated by
    :func:`arvcas.model.hydro.planar_drag`. ``frames``: the ``drag_frames`` of :func:`arm_schedule`.
    Equals the drag in :func:`rnea` (test_schedule.py). ``v_c_b``: the current in {b}, taken off the
    velocity of every point (the relative flow, docs/model.md §10).
    """
    rho = P["env.rho"]
    v_b, w_b = nu[0:3], nu[3:6]
    if v_c_b is not None:
        v_b = v_b - v_c_b
    s_list = link_vectors(P) if P.s.arm == "dh" else None
    F, N = 0, 0
    for j, i in enumerate(drag_links(P)):
        _, s, D_i, Cd = drag_segment(P, i, s_list)
        fr = frames[j * _DRAG_FRAME:(j + 1) * _DRAG_FRAME]
        Om, r, V, e1, e2 = fr[0:3], fr[3:6], fr[6:9], fr[9:12], fr[12:15]
        w = w_b + Om
        v = v_b + ca.cross(w_b, r) + V
        a = ca.vertcat(ca.dot(e1, v), ca.dot(e2, v))
        b = ca.vertcat(ca.dot(e2, w), -ca.dot(e1, w))  # components of w x u (u x e1 = e2, u x e2 = -e1)
        k = -0.5 * rho * Cd * D_i
        f2, m2 = hydro.planar_drag(k, ca.norm_2(s), a, b, n_quad)
        f = f2[0] * e1 + f2[1] * e2
        F = F + f
        N = N + (m2[0] * e2 - m2[1] * e1) + ca.cross(r, f)
    if isinstance(F, int):
        return ca.DM.zeros(6)
    return ca.vertcat(F, N)


def arm_wrench_scheduled(P, sched: dict, eta, nu, n_quad: int = 5, v_c_b=None):
    """tau_m at ``nu_dot = 0`` from the time-only terms of :func:`arm_schedule` and the vehicle state.

    Equal to ``arm_wrench(P, eta, nu, 0, q, qd, qdd, payload)`` up to round-off, at a fraction of its
    cost once the schedule is tabulated. ``sched`` holds the fields of :func:`schedule_fields` as
    matrices (``M_arm``, ``M_arm_dot`` 6x6) and vectors.
    """
    R = Rzyx(eta[3], eta[4], eta[5])
    g_b = ca.mtimes(R.T, ca.vertcat(0, 0, P["env.g"]))
    h = ca.mtimes(sched["M_arm"], nu) + sched["h_q"]
    v, w = nu[0:3], nu[3:6]
    nu_x_h = ca.vertcat(ca.cross(w, h[0:3]), ca.cross(w, h[3:6]) + ca.cross(v, h[0:3]))
    inertial = ca.mtimes(sched["M_arm_dot"], nu) + sched["b_q"] + nu_x_h
    weight = ca.vertcat(sched["W"] * g_b, ca.cross(sched["S"], g_b))
    return weight + drag_wrench(P, nu, sched["drag_frames"], n_quad, v_c_b) - inertial


def stow_pose(P):
    """q0 of section 4.2, the pose at which the vehicle is trimmed (docs/model.md §3)."""
    return ca.vertcat(*[P[f"arm.stow.q{i}"] for i in range(1, n_joints(P) + 1)])


def trim_static(P, n_quad: int = 5):
    """(F_z, M_x, M_y) of tau_m at q0, level, at rest, without payload (docs/model.md §3 trim)."""
    z6, zn = ca.DM.zeros(6), ca.DM.zeros(n_joints(P))
    tm = arm_wrench(P, z6, z6, z6, stow_pose(P), zn, zn, 0, n_quad)
    return tm[2], tm[3], tm[4]


TRIM_FZ_ZERO = 1e-100  # N: a static weight in water below this is zero for the trim (no overflow of M / F_z)


def trim_from_static(Fz, Mx, My, eta):
    """The fixed trim buoyancy of docs/model.md §3 in {b}, from the static wrench at q0.

    A world-vertical upward force F_z at r_t = [-M_y/F_z, M_x/F_z, 0]:
    ``f_t = R' [0, 0, -F_z]``, ``m_t = r_t x f_t``. Without the division: ``m_t = [-M_y, M_x, 0] x u``
    with ``u = R' [0, 0, -1]``; for an arm whose static weight in water is zero (``|F_z| <``
    :data:`TRIM_FZ_ZERO`, a neutrally buoyant arm) the moment is computed that way (the limit of a
    vanishing force at a receding point: a pure couple), so the trim is finite for every arm; for any
    other ``F_z`` the expression (and so every number) is the one above.
    """
    R = Rzyx(eta[3], eta[4], eta[5])
    Fs = ca.if_else(ca.fabs(Fz) < TRIM_FZ_ZERO, 1, Fz)  # = F_z exactly (F_z + 0) unless F_z is zero
    r_t = ca.vertcat(-My / Fs, Mx / Fs, 0)
    f_t = ca.mtimes(R.T, ca.vertcat(0, 0, -Fz))
    g_t = ca.mtimes(R.T, ca.vertcat(0, 0, -Fs))  # = f_t, or u for a neutral arm
    return ca.vertcat(f_t, ca.cross(r_t, g_t))


def has_trim(P) -> bool:
    """Whether the system gets docs/model.md §3's trim: an arm, and not ``[arm] trim = false``."""
    return n_joints(P) > 0 and P.s.arm_trim


def trim_wrench(P, eta, n_quad: int = 5):
    """The trim of docs/model.md §3 at attitude ``eta``, computed from the same parameters (follows rho, links).

    Zero for a system without an arm or with ``[arm] trim = false`` (its vehicle carries its own ballast)."""
    if not has_trim(P):
        return ca.DM.zeros(6)
    return trim_from_static(*trim_static(P, n_quad), eta)
