"""The 6-DOF deep-sea manipulator: modified DH kinematics and recursive Newton-Euler on a moving base.

Paper eq. 7-11 with docs/model.md §3: Craig's modified DH (Table 1), link i spans origin {i} -> origin {i+1}
(link 6: ``[0, 0, L_tool]`` along z6), centre of mass and of buoyancy at the middle of each link,
solid-cylinder inertia, per-link buoyancy and quadrature drag, a point payload at the tool point.
The base is the vehicle: frame {0} sits at ``P^b_0`` in {b} with ``R^b_0 = I``.

Sign convention: :func:`arm_wrench` returns ``tau_m``, the wrench the arm exerts *on the vehicle*,
in {b} about the COB (at rest and level its z force is the arm's weight in water, positive down).
"""

from __future__ import annotations

import casadi as ca

from arvcas.model import hydro
from arvcas.model.spatial import Rx, Rz, Rzyx, skew

__all__ = [
    "N_JOINTS", "dh", "link_vectors", "link_inertia", "forward_kinematics", "rnea", "arm_wrench",
    "stow_pose", "trim_wrench", "trim_static", "trim_from_static", "base_inertia",
    "SCHEDULE_FIELDS", "arm_schedule", "drag_wrench", "arm_wrench_scheduled",
]

N_JOINTS = 6
_Z = ca.DM([0, 0, 1])


def dh(P, i: int, q_i):
    """Modified DH transform of joint i (1-based): T_{i-1,i} = RotX(alpha) TransX(a) RotZ(q) TransZ(d).

    Returns (R^{i-1}_i, p^{i-1}_i).
    """
    a, d, al = P[f"arm.joint{i}.a"], P[f"arm.joint{i}.d"], P[f"arm.joint{i}.alpha"]
    R = ca.mtimes(Rx(al), Rz(q_i))
    p = ca.vertcat(a, -ca.sin(al) * d, ca.cos(al) * d)
    return R, p


def link_vectors(P):
    """s_i = P^i_{i+1} for links 1..6 (docs/model.md §3); s_6 reaches the tool point along z6."""
    s = []
    for i in range(1, N_JOINTS):
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


def forward_kinematics(P, q):
    """Pose of frames {1..6} in {0}: list of (R^0_i, p^0_i)."""
    R, p = ca.DM.eye(3), ca.DM.zeros(3)
    out = []
    for i in range(1, N_JOINTS + 1):
        Ri, pi = dh(P, i, q[i - 1])
        p = p + ca.mtimes(R, pi)
        R = ca.mtimes(R, Ri)
        out.append((R, p))
    return out




def rnea(P, q, qd, qdd, w0, wd0, v0, a0, g0, payload, n_quad: int = 5, drag: bool = True):
    """Recursive Newton-Euler (paper eq. 7, 8, 10) on a base frame {0} moving with (w0, wd0, v0, a0).

    All base quantities are in {0}: angular velocity/acceleration, velocity and absolute acceleration of
    the origin, gravity vector ``g0`` (m/s^2); ``drag=False`` leaves the fluid drag out. Returns (f_1, n_1, R^0_1, p^0_1): the force and moment the
    base exerts on link 1 at origin {1}, in frame {1}.
    """
    rho, Cd = P["env.rho"], P["env.Cd"]
    s_list = link_vectors(P)
    w, wd, v, a, g = w0, wd0, v0, a0, g0
    frames = []
    kin = []
    for i in range(1, N_JOINTS + 1):
        Ri, pi = dh(P, i, q[i - 1])
        RiT = Ri.T
        # eq. 7: propagate to frame i (quantities of frame i-1 first moved by p_i)
        a = ca.mtimes(RiT, a + ca.cross(wd, pi) + ca.cross(w, ca.cross(w, pi)))
        v = ca.mtimes(RiT, v + ca.cross(w, pi))
        w_prev = ca.mtimes(RiT, w)
        w = w_prev + qd[i - 1] * _Z
        wd = ca.mtimes(RiT, wd) + ca.cross(w_prev, qd[i - 1] * _Z) + qdd[i - 1] * _Z
        g = ca.mtimes(RiT, g)
        frames.append((Ri, pi))
        kin.append((w, wd, v, a, g))

    f_next, n_next = ca.DM.zeros(3), ca.DM.zeros(3)
    for i in range(N_JOINTS, 0, -1):
        w, wd, v, a, g = kin[i - 1]
        s = s_list[i - 1]
        m_i = P[f"arm.link{i}.mass"]
        V_i = P[f"arm.link{i}.volume"]
        D_i = P[f"arm.link{i}.diameter"]
        c = 0.5 * s  # COM = COB at the middle of the link (docs/model.md §3)
        a_c = a + ca.cross(wd, c) + ca.cross(w, ca.cross(w, c))
        F = m_i * a_c  # eq. 8
        Ic = link_inertia(m_i, D_i, s)
        N = ca.mtimes(Ic, wd) + ca.cross(w, ca.mtimes(Ic, w))
        ext_c = m_i * g + hydro.buoyancy_force(rho, V_i, g)  # weight + buoyancy, both at c
        f_d, n_d = hydro.link_drag(rho, Cd, D_i, s, v, w, n_quad) if drag else (0, 0)
        if i < N_JOINTS:
            R_next, p_next = frames[i]
            f_child = ca.mtimes(R_next, f_next)
            n_child = ca.mtimes(R_next, n_next) + ca.cross(p_next, f_child)
        else:
            # payload: point mass at the tool point, scaled by payload in [0, 1] (docs/model.md §3)
            t = s
            a_t = a + ca.cross(wd, t) + ca.cross(w, ca.cross(w, t))
            mp, Vp = P["payload.mass"], P["payload.volume"]
            f_child = payload * (mp * a_t - mp * g - hydro.buoyancy_force(rho, Vp, g))
            n_child = ca.cross(t, f_child)
        # eq. 10 with explicit external loads: what the parent must supply
        f_next = f_child + F - ext_c - f_d
        n_next = n_child + N + ca.cross(c, F - ext_c) - n_d
    R1, p1 = frames[0]
    return f_next, n_next, R1, p1


def arm_wrench(P, eta, nu, nud, q, qd, qdd, payload, n_quad: int = 5):
    """tau_m of eq. 11: the arm's wrench on the vehicle in {b} about the COB (docs/model.md §3 sign).

    ``nud`` is Fossen's nu_dot (time derivative of the body-frame velocity components).
    """
    pb0 = ca.vertcat(P["arm.mount.x"], P["arm.mount.y"], P["arm.mount.z"])  # R^b_0 = I (docs/model.md §3)
    v_b, w_b = nu[0:3], nu[3:6]
    a_b = nud[0:3] + ca.cross(w_b, v_b)  # absolute acceleration of the COB, in {b}
    wd_b = nud[3:6]
    w0, wd0 = w_b, wd_b
    v0 = v_b + ca.cross(w_b, pb0)
    a0 = a_b + ca.cross(wd_b, pb0) + ca.cross(w_b, ca.cross(w_b, pb0))
    R = Rzyx(eta[3], eta[4], eta[5])
    g0 = ca.mtimes(R.T, ca.vertcat(0, 0, P["env.g"]))
    f1, n1, R1, p1 = rnea(P, q, qd, qdd, w0, wd0, v0, a0, g0, payload, n_quad)
    return -_to_cob(P, f1, n1, R1, p1)


def _bodies(P, q, payload):
    """The arm's bodies in {b}: links 1..6 and the payload point mass at the tool point.

    Each entry: ``m`` (mass), ``m_wet`` (mass minus displaced water), ``c`` (centre in {b}), ``r``
    (centre from the origin of its link's frame, in {b}), the cylinder inertia about ``c`` as ``I_tr I + k_ax Rs Rs'`` (``Rs``: the link vector in {b}; ``None``
    and zeros for the payload), and ``link`` (the link the body rides on).
    """
    pb0 = ca.vertcat(P["arm.mount.x"], P["arm.mount.y"], P["arm.mount.z"])
    rho = P["env.rho"]
    s_list = link_vectors(P)
    out = []
    for i, (R, p) in enumerate(forward_kinematics(P, q), start=1):
        s = s_list[i - 1]
        m_i = P[f"arm.link{i}.mass"]
        L2 = ca.dot(s, s)
        r2 = (0.5 * P[f"arm.link{i}.diameter"]) ** 2
        I_ax = 0.5 * m_i * r2
        I_tr = m_i * (3 * r2 + L2) / 12.0
        Rs = ca.mtimes(R, s)
        out.append(dict(m=m_i, m_wet=m_i - rho * P[f"arm.link{i}.volume"], c=pb0 + p + 0.5 * Rs, r=0.5 * Rs,
                        I_tr=I_tr, k_ax=(I_ax - I_tr) / L2, Rs=Rs, link=i))
        if i == N_JOINTS:
            mp = P["payload.mass"]
            out.append(dict(m=payload * mp, m_wet=payload * (mp - rho * P["payload.volume"]), c=pb0 + p + Rs, r=Rs,
                            I_tr=0, k_ax=0, Rs=None, link=i))
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
    return _spatial_inertia(mass, first, J)


# The time-only part of the arm's wrench: everything that depends on (q, qd, qdd, payload) and p but
# not on the vehicle state. (name, size); matrices are 6x6 symmetric, stored as their upper triangle.
SCHEDULE_FIELDS: tuple[tuple[str, int], ...] = (
    ("M_arm", 21), ("M_arm_dot", 21), ("h_q", 6), ("b_q", 6), ("W", 1), ("S", 3), ("drag_frames", 15 * N_JOINTS),
)
# per link in drag_frames: Omega (3), r (3), V (3), e1 (3), e2 (3); see arm_schedule
_DRAG_FRAME = 15


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
    s_list = link_vectors(P)
    w = ca.DM.zeros(3)
    v_o = ca.DM.zeros(3)
    p_prev = ca.DM.zeros(3)
    link_w, link_vo = {}, {}
    frames = []
    for i, (R, p) in enumerate(forward_kinematics(P, q), start=1):
        v_o = v_o + ca.cross(w, p - p_prev)  # origin i is fixed in link i-1
        w = w + qd[i - 1] * ca.mtimes(R, _Z)
        link_w[i], link_vo[i] = w, v_o
        p_prev = p
        s = s_list[i - 1]
        e1, e2 = hydro.normal_basis(s / ca.norm_2(s))
        frames += [w, pb0 + p, v_o, ca.mtimes(R, e1), ca.mtimes(R, e2)]
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
        h_ang = h_ang + Iw + ca.cross(c, mcd)
        # d/dt of m (|c|^2 I - c c') + k_ax Rs Rs', with d(Rs)/dt = w x Rs
        first_dot = first_dot + mcd
        mc = m * c
        J_dot = J_dot + (2 * ca.dot(mc, c_dot)) * ca.DM.eye(3) - ca.mtimes(mcd, c.T) - ca.mtimes(mc, c_dot.T)
        if b["Rs"] is not None:
            d = ca.cross(w, b["Rs"])
            J_dot = J_dot + b["k_ax"] * (ca.mtimes(d, b["Rs"].T) + ca.mtimes(b["Rs"], d.T))
        W = W + b["m_wet"]
        S = S + b["m_wet"] * c
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
    """A wrench at origin {1} in frame {1} moved to the COB in {b} (R^b_0 = I, docs/model.md §3)."""
    pb0 = ca.vertcat(P["arm.mount.x"], P["arm.mount.y"], P["arm.mount.z"])
    f0 = ca.mtimes(R1, f1)
    n0 = ca.mtimes(R1, n1) + ca.cross(p1, f0)
    return ca.vertcat(f0, n0 + ca.cross(pb0, f0))


def drag_wrench(P, nu, frames, n_quad: int = 5):
    """The water's drag on the whole arm as a wrench at the COB in {b} (eq. 9 by quadrature, docs/model.md §3).

    Everything in {b}: link i turns at ``w_i = w + Omega_i`` and its origin moves at
    ``v + w x r_i + V_i`` (the vehicle's ``nu = [v; w]`` plus the joint motion); the normal velocity
    along the link, in the basis ``e1, e2``, is affine in x and integrated by
    :func:`arvcas.model.hydro.planar_drag`. ``frames``: the ``drag_frames`` of :func:`arm_schedule`.
    Equals the drag in :func:`rnea` (test_schedule.py).
    """
    rho, Cd = P["env.rho"], P["env.Cd"]
    v_b, w_b = nu[0:3], nu[3:6]
    s_list = link_vectors(P)
    F, N = 0, 0
    for i in range(1, N_JOINTS + 1):
        fr = frames[(i - 1) * _DRAG_FRAME:i * _DRAG_FRAME]
        Om, r, V, e1, e2 = fr[0:3], fr[3:6], fr[6:9], fr[9:12], fr[12:15]
        w = w_b + Om
        v = v_b + ca.cross(w_b, r) + V
        a = ca.vertcat(ca.dot(e1, v), ca.dot(e2, v))
        b = ca.vertcat(ca.dot(e2, w), -ca.dot(e1, w))  # components of w x u (u x e1 = e2, u x e2 = -e1)
        k = -0.5 * rho * Cd * P[f"arm.link{i}.diameter"]
        f2, m2 = hydro.planar_drag(k, ca.norm_2(s_list[i - 1]), a, b, n_quad)
        f = f2[0] * e1 + f2[1] * e2
        F = F + f
        N = N + (m2[0] * e2 - m2[1] * e1) + ca.cross(r, f)
    return ca.vertcat(F, N)


def arm_wrench_scheduled(P, sched: dict, eta, nu, n_quad: int = 5):
    """tau_m at ``nu_dot = 0`` from the time-only terms of :func:`arm_schedule` and the vehicle state.

    Equal to ``arm_wrench(P, eta, nu, 0, q, qd, qdd, payload)`` up to round-off, at a fraction of its
    cost once the schedule is tabulated. ``sched`` holds the fields of :data:`SCHEDULE_FIELDS` as
    matrices (``M_arm``, ``M_arm_dot`` 6x6) and vectors.
    """
    R = Rzyx(eta[3], eta[4], eta[5])
    g_b = ca.mtimes(R.T, ca.vertcat(0, 0, P["env.g"]))
    h = ca.mtimes(sched["M_arm"], nu) + sched["h_q"]
    v, w = nu[0:3], nu[3:6]
    nu_x_h = ca.vertcat(ca.cross(w, h[0:3]), ca.cross(w, h[3:6]) + ca.cross(v, h[0:3]))
    inertial = ca.mtimes(sched["M_arm_dot"], nu) + sched["b_q"] + nu_x_h
    weight = ca.vertcat(sched["W"] * g_b, ca.cross(sched["S"], g_b))
    return weight + drag_wrench(P, nu, sched["drag_frames"], n_quad) - inertial


def stow_pose(P):
    """q0 of section 4.2, the pose at which the vehicle is trimmed (docs/model.md §3)."""
    return ca.vertcat(*[P[f"arm.stow.q{i}"] for i in range(1, N_JOINTS + 1)])


def trim_static(P, n_quad: int = 5):
    """(F_z, M_x, M_y) of tau_m at q0, level, at rest, without payload (docs/model.md §3 trim)."""
    z6 = ca.DM.zeros(6)
    tm = arm_wrench(P, z6, z6, z6, stow_pose(P), z6, z6, 0, n_quad)
    return tm[2], tm[3], tm[4]


def trim_from_static(Fz, Mx, My, eta):
    """The fixed trim buoyancy of docs/model.md §3 in {b}, from the static wrench at q0.

    A world-vertical upward force F_z at r_t = [-M_y/F_z, M_x/F_z, 0]:
    ``f_t = R' [0, 0, -F_z]``, ``m_t = r_t x f_t``.
    """
    r_t = ca.vertcat(-My / Fz, Mx / Fz, 0)
    R = Rzyx(eta[3], eta[4], eta[5])
    f_t = ca.mtimes(R.T, ca.vertcat(0, 0, -Fz))
    return ca.vertcat(f_t, ca.cross(r_t, f_t))


def trim_wrench(P, eta, n_quad: int = 5):
    """The trim of docs/model.md §3 at attitude ``eta``, computed from the same parameters (follows rho, links)."""
    return trim_from_static(*trim_static(P, n_quad), eta)
