"""Systems loaded from files against Pinocchio built from the URDF.

The API under test (docs/system-file.md):

- ``system = arvcas.load_system(name_or_path)`` with ``.n_joints``, ``.n_thrusters``, ``.params``
  (``.names()``, ``.vector()``, ``.replace({name: SI value})``);
- ``arvcas.compiled("arm_wrench", system=system)``: (eta[6], nu[6], nud[6], q[n], qd[n], qdd[n],
  payload[1], p) -> tau_m[6], the wrench the arm + payload exert ON the vehicle, in {b} about the body
  origin; ``arvcas.compiled("uvms_rhs", system=system)``: (x[12], tau[6], q[n], qd[n], qdd[n],
  payload[1], p) -> xdot[12], the trim of docs/model.md §3 at the stow pose included.

Checks:

1. Random arms of 1..7 joints written as URDF (tests/urdf_arms.py: random origins, axes not along
   x/y/z, full inertia tensors, CoM offsets; one variant with a fixed flange joint, a continuous joint
   and a tool link or none) on a random vehicle with 8 thrusters (docs/system-file.md form 3). With
   ``env.rho = 0`` and every ``hydro.*`` term zeroed, nothing but rigid-body dynamics under gravity is
   left: ``arm_wrench`` equals Pinocchio's RNEA (tests/pinocchio_urdf.py, the same URDF read by
   Pinocchio) and ``uvms_rhs``'s nu_dot its forward dynamics with prescribed joint accelerations, both to
   1e-9 relative (buoyancy rho g V = 0; the trim from Pinocchio's static wrench at the stow pose).
   Also: a second file of the same structure is served by the same compiled function, and the vehicle
   alone (no ``[arm]``, n_joints = 0) is Pinocchio's free flyer.
2. Haidou-1 two ways: ``load_system("haidou1")`` (DH table) and a form-3 file written from it (its arm
   as URDF by ``urdf_arms.haidou1_urdf``, the same cylinders as ``[arm.hydro.*]``, everything else the
   shipped text): ``arm_wrench`` and ``uvms_rhs`` equal to 1e-12 relative, in water (rho as in the
   file). Both also against the Pinocchio reference at rho = 0 (1e-9).
3. Bad URDF input: a one-line ValueError naming the file and the element, from ``load_system``.
"""

from __future__ import annotations

import numpy as np
import pytest

import arvcas
import pinocchio_model as pm
import pinocchio_urdf as pu
import urdf_arms as ua

RTOL = 1e-9  # against Pinocchio
RTOL_TWO_WAYS = 1e-12  # Haidou-1's DH table against its URDF
N_STATES = 8


def _values(params) -> dict[str, float]:
    return dict(zip(params.names(), np.asarray(params.vector(), float)))


def _dry(params):
    """rho = 0 and every vehicle hydrodynamic term zero: no fluid anywhere (SI terms do not scale with rho)."""
    hydro = [k for k in params.names() if k.startswith("hydro.")]
    return params.replace({"env.rho": 0.0, **{k: 0.0 for k in hydro}})


def _rel(got, ref) -> float:
    return float(np.linalg.norm(np.asarray(got) - np.asarray(ref)) / np.linalg.norm(ref))


def _call(fn, *args) -> np.ndarray:
    return np.array(fn(*args)).ravel()


_state = pu.random_state


class _Systems:
    """Random systems written to a temporary directory and loaded once per module, with their references."""

    def __init__(self, tmp_path_factory):
        self.tmp = tmp_path_factory
        self.loaded = {}

    def get(self, n: int, variant: str):
        key = (n, variant)
        if key not in self.loaded:
            arm = ua.case_arm(n, variant)
            path = arm.write(self.tmp.mktemp(f"arm{n}_{variant}"))
            system = arvcas.load_system(str(path))
            self.loaded[key] = (arm, system, pu.build_for(arm, g=9.81))
        return self.loaded[key]


@pytest.fixture(scope="module")
def systems(tmp_path_factory, cache):
    return _Systems(tmp_path_factory)


def _fns(system):
    return arvcas.compiled("arm_wrench", system=system), arvcas.compiled("uvms_rhs", system=system)


# ---- 1. random URDF arms -------------------------------------------------------------------------------


@pytest.mark.parametrize("n,variant", ua.ARM_CASES)
def test_random_system_loads(systems, n, variant):
    arm, system, _ = systems.get(n, variant)
    assert system.n_joints == n
    assert system.n_thrusters == 8
    v = _values(system.params)
    assert len(system.params.vector()) == len(system.params.names()) == len(v)
    assert v["env.rho"] == 1025.0 and v["env.g"] == 9.81
    assert v["vehicle.m"] == arm.vehicle_mass
    assert any(k.startswith("hydro.") for k in v), "no hydro.* parameter: _dry() would leave the fluid in"
    # the URDF's limits and the stow pose, held as form 2 (docs/system-file.md: arm.joint<i>.qmin ...)
    for i, (lo, hi, q0) in enumerate(zip(arm.qmin, arm.qmax, arm.q_stow), start=1):
        assert v[f"arm.stow.q{i}"] == q0
        if np.isfinite(lo):
            assert (v[f"arm.joint{i}.qmin"], v[f"arm.joint{i}.qmax"]) == (lo, hi)


@pytest.mark.parametrize("n,variant", ua.ARM_CASES)
def test_random_arm_wrench_matches_pinocchio(systems, n, variant):
    arm, system, ref = systems.get(n, variant)
    f_arm, _ = _fns(system)
    p = _dry(system.params).vector()
    rng = np.random.default_rng(10 * n + len(variant))
    worst = 0.0
    for k in range(N_STATES):
        s = _state(rng, arm.qmin, arm.qmax)
        payload = (0.0, 0.5, 1.0)[k % 3]
        got = _call(f_arm, *s, payload, p)
        want = pu.arm_wrench_on_vehicle(ref, *s, payload_mass=payload * arm.payload_mass)
        worst = max(worst, _rel(got, want))
    print(f"{n} joints, {variant}: arm_wrench max relative error {worst:.2e}")
    assert worst < RTOL, f"max relative error {worst:.3e}"


@pytest.mark.parametrize("n,variant", ua.ARM_CASES)
def test_random_uvms_rhs_matches_pinocchio(systems, n, variant):
    """nu_dot from Pinocchio: M[0:6,0:6] nu_dot = trim + tau - (nle + M[0:6,6:] qdd)[0:6], the trim a
    world-vertical force F_z at [-M_y/F_z, M_x/F_z, 0] from the static wrench at the stow pose."""
    arm, system, ref = systems.get(n, variant)
    _, f_rhs = _fns(system)
    p = _dry(system.params).vector()
    trim = pu.static_trim(ref, arm.q_stow)
    rng = np.random.default_rng(20 * n + len(variant))
    worst_nud = worst_etad = 0.0
    for k in range(N_STATES):
        eta, nu, _, q, qd, qdd = _state(rng, arm.qmin, arm.qmax)
        tau = 30 * rng.normal(size=6)
        payload = (0.0, 0.5, 1.0)[k % 3]
        xd = _call(f_rhs, np.concatenate([eta, nu]), tau, q, qd, qdd, payload, p)
        w = pu.trim_wrench(trim, eta) + tau  # rho = 0: no buoyancy on a `volume` vehicle
        nud = pu.vehicle_accel(ref, eta, nu, q, qd, qdd, w, payload_mass=payload * arm.payload_mass)
        worst_nud = max(worst_nud, _rel(xd[6:], nud))
        worst_etad = max(worst_etad, _rel(xd[:6], pm.J_eta(eta) @ nu))
    print(f"{n} joints, {variant}: nu_dot {worst_nud:.2e}, eta_dot {worst_etad:.2e}")
    assert worst_nud < RTOL and worst_etad < RTOL, (worst_nud, worst_etad)


@pytest.mark.parametrize("n,variant", [(3, "plain"), (6, "fixed_continuous")])
def test_random_trim_balances_at_stow(systems, n, variant):
    """At the stow pose, level, at rest, no payload, rho = 0, with tau holding the vehicle's own weight
    (m g at r_G): nothing accelerates (the trim cancels the arm's static wrench exactly)."""
    arm, system, _ = systems.get(n, variant)
    _, f_rhs = _fns(system)
    p = _dry(system.params).vector()
    W = arm.vehicle_mass * 9.81
    f = np.array([0.0, 0.0, -W])
    tau = np.concatenate([f, np.cross(arm.vehicle_com, f)])
    z = np.zeros(n)
    xd = _call(f_rhs, np.zeros(12), tau, arm.q_stow, z, z, 0.0, p)
    assert np.abs(xd).max() < 1e-12 * max(1.0, W / arm.vehicle_mass)


def test_same_structure_other_numbers(systems, tmp_path):
    """Another random arm of the same structure (joint count, link names, sections): the same parameter
    names, and the function compiled for the first system is right for the second one's numbers."""
    arm_a, system_a, _ = systems.get(4, "plain")
    arm_b = ua.case_arm(4, "plain", seed=1)
    system_b = arvcas.load_system(str(arm_b.write(tmp_path)))
    assert system_b.params.names() == system_a.params.names()
    assert not np.array_equal(system_b.params.vector(), system_a.params.vector())
    f_arm, f_rhs = _fns(system_a)
    p = _dry(system_b.params).vector()
    ref = pu.build_for(arm_b)
    trim = pu.static_trim(ref, arm_b.q_stow)
    rng = np.random.default_rng(30)
    for _ in range(N_STATES):
        eta, nu, nud, q, qd, qdd = _state(rng, arm_b.qmin, arm_b.qmax)
        want = pu.arm_wrench_on_vehicle(ref, eta, nu, nud, q, qd, qdd, payload_mass=arm_b.payload_mass)
        assert _rel(_call(f_arm, eta, nu, nud, q, qd, qdd, 1.0, p), want) < RTOL
        tau = 30 * rng.normal(size=6)
        xd = _call(f_rhs, np.concatenate([eta, nu]), tau, q, qd, qdd, 1.0, p)
        nud_ref = pu.vehicle_accel(ref, eta, nu, q, qd, qdd, pu.trim_wrench(trim, eta) + tau,
                                   payload_mass=arm_b.payload_mass)
        assert _rel(xd[6:], nud_ref) < RTOL


def test_vehicle_alone(tmp_path, cache):
    """No [arm]: n_joints = 0, q/qd/qdd of size 0; arm_wrench is zero and uvms_rhs is the free-flying
    vehicle under gravity and tau (no trim to make: the trim rule must not divide by a zero weight)."""
    arm = ua.random_arm(np.random.default_rng(90), 0)
    system = arvcas.load_system(str(arm.write(tmp_path)))
    assert system.n_joints == 0 and system.n_thrusters == 8
    f_arm, f_rhs = _fns(system)
    p = _dry(system.params).vector()
    ref = pu.build_for(arm)
    rng = np.random.default_rng(91)
    e = np.zeros(0)
    for _ in range(N_STATES):
        eta, nu, nud, _, _, _ = _state(rng, e, e)
        tau = 30 * rng.normal(size=6)
        assert not _call(f_arm, eta, nu, nud, e, e, e, 0.0, p).any()
        xd = _call(f_rhs, np.concatenate([eta, nu]), tau, e, e, e, 0.0, p)
        assert np.isfinite(xd).all()
        assert _rel(xd[6:], pu.vehicle_accel(ref, eta, nu, e, e, e, tau)) < RTOL
        assert _rel(xd[:6], pm.J_eta(eta) @ nu) < RTOL


# ---- 2. Haidou-1 two ways ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def haidou(tmp_path_factory, cache):
    """(DH system, URDF system, the DH system's SI values by name)."""
    dh = arvcas.load_system("haidou1")
    v = _values(dh.params)
    d = tmp_path_factory.mktemp("haidou1_urdf")
    (d / "haidou1_arm.urdf").write_text(ua.haidou1_urdf(v))
    path = d / "haidou1_urdf.toml"
    path.write_text(ua.haidou1_form3_toml(ua.shipped_haidou1_text(), v, urdf_name="haidou1_arm.urdf"))
    return dh, arvcas.load_system(str(path)), v


def _haidou_limits(v):
    return (np.array([v[f"arm.joint{i}.qmin"] for i in range(1, 7)]),
            np.array([v[f"arm.joint{i}.qmax"] for i in range(1, 7)]))


def test_haidou1_two_ways_load(haidou):
    dh, urdf, v = haidou
    assert dh.n_joints == urdf.n_joints == 6
    assert dh.n_thrusters == urdf.n_thrusters == 6
    vu = _values(urdf.params)
    for k in ("env.rho", "env.g", "env.Cd", "vehicle.m", "payload.mass", "payload.volume", "arm.mount.x",
              "arm.mount.z", "arm.stow.q2"):
        assert vu[k] == v[k], k


@pytest.mark.parametrize("payload", [0.0, 1.0])
def test_haidou1_two_ways_arm_wrench(haidou, payload):
    dh, urdf, v = haidou
    fa, fb = _fns(dh)[0], _fns(urdf)[0]
    pa, pb = dh.params.vector(), urdf.params.vector()
    rng = np.random.default_rng(50 + int(payload))
    worst = 0.0
    for _ in range(2 * N_STATES):
        s = _state(rng, *_haidou_limits(v))
        worst = max(worst, _rel(_call(fb, *s, payload, pb), _call(fa, *s, payload, pa)))
    print(f"payload {payload}: DH vs URDF arm_wrench {worst:.2e}")
    assert worst < RTOL_TWO_WAYS, worst


def test_haidou1_two_ways_uvms_rhs(haidou):
    dh, urdf, v = haidou
    fa, fb = _fns(dh)[1], _fns(urdf)[1]
    pa, pb = dh.params.vector(), urdf.params.vector()
    rng = np.random.default_rng(60)
    worst = 0.0
    for k in range(2 * N_STATES):
        eta, nu, _, q, qd, qdd = _state(rng, *_haidou_limits(v))
        x, tau, payload = np.concatenate([eta, nu]), 300 * rng.normal(size=6), (0.0, 0.5, 1.0)[k % 3]
        worst = max(worst, _rel(_call(fb, x, tau, q, qd, qdd, payload, pb), _call(fa, x, tau, q, qd, qdd, payload, pa)))
    print(f"DH vs URDF uvms_rhs {worst:.2e}")
    assert worst < RTOL_TWO_WAYS, worst


@pytest.mark.parametrize("form", ["dh", "urdf"])
def test_haidou1_matches_pinocchio_dry(haidou, form):
    """Both forms against Pinocchio from the URDF at rho = 0: arm_wrench, and uvms_rhs with the buoyancy
    B = (m + buoyancy_excess) g at r_B (does not follow rho) and the trim at the stow pose."""
    dh, urdf, v = haidou
    system = dh if form == "dh" else urdf
    f_arm, f_rhs = _fns(system)
    p = _dry(system.params).vector()
    I_o = np.array([[v["vehicle.Ixx"], -v["vehicle.Ixy"], -v["vehicle.Ixz"]],
                    [-v["vehicle.Ixy"], v["vehicle.Iyy"], -v["vehicle.Iyz"]],
                    [-v["vehicle.Ixz"], -v["vehicle.Iyz"], v["vehicle.Izz"]]])
    ref = pu.build(ua.haidou1_urdf(v), [v["arm.mount.x"], v["arm.mount.y"], v["arm.mount.z"]], np.zeros(3),
                   v["vehicle.m"], I_o, [v["vehicle.xG"], v["vehicle.yG"], v["vehicle.zG"]], g=v["env.g"])
    trim = pu.static_trim(ref, np.array([v[f"arm.stow.q{i}"] for i in range(1, 7)]))
    B = (v["vehicle.m"] + v["vehicle.buoyancy_excess"]) * v["env.g"]
    rB = [v["vehicle.xB"], v["vehicle.yB"], v["vehicle.zB"]]
    rng = np.random.default_rng(70)
    for k in range(N_STATES):
        eta, nu, nud, q, qd, qdd = _state(rng, *_haidou_limits(v))
        payload = (0.0, 0.5, 1.0)[k % 3]
        mp = payload * v["payload.mass"]
        want = pu.arm_wrench_on_vehicle(ref, eta, nu, nud, q, qd, qdd, payload_mass=mp)
        assert _rel(_call(f_arm, eta, nu, nud, q, qd, qdd, payload, p), want) < RTOL
        tau = 300 * rng.normal(size=6)
        xd = _call(f_rhs, np.concatenate([eta, nu]), tau, q, qd, qdd, payload, p)
        w = pu.buoyancy_wrench(B, rB, eta) + pu.trim_wrench(trim, eta) + tau
        assert _rel(xd[6:], pu.vehicle_accel(ref, eta, nu, q, qd, qdd, w, payload_mass=mp)) < RTOL


# ---- 3. bad URDF input -----------------------------------------------------------------------------------


def _load_error(tmp_path, arm: ua.RandomArm) -> str:
    path = arm.write(tmp_path)
    with pytest.raises(ValueError) as ei:
        arvcas.load_system(str(path))
    msg = str(ei.value)
    assert "\n" not in msg, f"not one line: {msg!r}"
    assert arm.urdf_name in msg or path.name in msg, f"names neither file: {msg!r}"
    return msg


def test_prismatic_joint_refused(tmp_path):
    arm = ua.bad_urdf(ua.random_arm(np.random.default_rng(80), 3), "prismatic")
    msg = _load_error(tmp_path, arm)
    assert "joint2" in msg and "prismatic" in msg, msg
    assert "revolute" in msg and "continuous" in msg, f"does not say which types are supported: {msg!r}"


def test_link_without_inertial_refused(tmp_path):
    arm = ua.bad_urdf(ua.random_arm(np.random.default_rng(81), 3), "no_inertial")
    msg = _load_error(tmp_path, arm)
    assert "link2" in msg and "inertial" in msg, msg


def test_eight_joints_refused(tmp_path):
    arm = ua.random_arm(np.random.default_rng(82), 8)
    msg = _load_error(tmp_path, arm)
    assert "7" in msg, f"does not say the limit (7 joints): {msg!r}"


def test_indefinite_link_inertia_refused(tmp_path):
    arm = ua.bad_urdf(ua.random_arm(np.random.default_rng(83), 3), "not_pd")
    msg = _load_error(tmp_path, arm)
    assert "link2" in msg and "inertia" in msg, msg


# ---- 4. the shipped BlueROV2's arm (written in the file, chain form) ------------------------------------


def _chain_urdf(v: dict, n: int) -> str:
    """The chain-form arm of a loaded system, written as URDF (the reference reads it with Pinocchio)."""
    vec = lambda k: np.array([v[f"{k}.{c}"] for c in "xyz"])  # noqa: E731
    links = [ua.LinkSpec("base_link")]
    joints = []
    for i in range(1, n + 1):
        ks = [f"arm.link{i}.inertia.{e}" for e in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")]
        ixx, iyy, izz, ixy, ixz, iyz = (v[k] for k in ks)
        I = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        links.append(ua.LinkSpec(f"link{i}", v[f"arm.link{i}.mass"], vec(f"arm.link{i}.com"), np.zeros(3), I))
        j = f"arm.joint{i}"
        joints.append(ua.JointSpec(f"joint{i}", "revolute", "base_link" if i == 1 else f"link{i - 1}", f"link{i}",
                                   np.array([v[j + ".x"], v[j + ".y"], v[j + ".z"]]),
                                   np.array([v[j + ".roll"], v[j + ".pitch"], v[j + ".yaw"]]), vec(j + ".axis"),
                                   v[j + ".qmin"], v[j + ".qmax"]))
    links.append(ua.LinkSpec("tool_link"))
    joints.append(ua.JointSpec("tool", "fixed", f"link{n}", "tool_link",
                               np.array([v["arm.tool.x"], v["arm.tool.y"], v["arm.tool.z"]]), np.zeros(3)))
    return ua.urdf_text("chain", links, joints)


def test_bluerov2_arm_matches_pinocchio_dry():
    """The shipped BlueROV2 + Alpha 5 (mount rotation, full link tensors off the joint axes): arm_wrench
    at rho = 0 against Pinocchio built from its arm written as URDF, to 1e-9 relative."""
    system = arvcas.load_system("bluerov2_heavy_alpha5")
    dry = _dry(system.params)
    v = _values(dry)
    n = system.n_joints
    I_o = np.array([[v["vehicle.Ixx"], -v["vehicle.Ixy"], -v["vehicle.Ixz"]],
                    [-v["vehicle.Ixy"], v["vehicle.Iyy"], -v["vehicle.Iyz"]],
                    [-v["vehicle.Ixz"], -v["vehicle.Iyz"], v["vehicle.Izz"]]])
    mount = [v[f"arm.mount.{k}"] for k in ("x", "y", "z")], [v[f"arm.mount.{k}"] for k in ("roll", "pitch", "yaw")]
    ref = pu.build(_chain_urdf(v, n), *mount, v["vehicle.m"], I_o,
                   [v["vehicle.xG"], v["vehicle.yG"], v["vehicle.zG"]], g=v["env.g"])
    f_arm = arvcas.compiled("arm_wrench", system=system)
    qmin = np.array([v[f"arm.joint{i}.qmin"] for i in range(1, n + 1)])
    qmax = np.array([v[f"arm.joint{i}.qmax"] for i in range(1, n + 1)])
    rng = np.random.default_rng(77)
    worst = 0.0
    for k in range(N_STATES):
        s = _state(rng, qmin, qmax)
        payload = (0.0, 1.0)[k % 2]
        got = _call(f_arm, *s, payload, dry.vector())
        want = pu.arm_wrench_on_vehicle(ref, *s, payload_mass=payload * v["payload.mass"])
        worst = max(worst, _rel(got, want))
    assert worst < RTOL, f"max relative error {worst:.3e}"
