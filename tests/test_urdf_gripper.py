"""A URDF arm with a gripper: the fingers locked, the chain's end and tool point chosen.

The arm is a random 4-joint arm of tests/urdf_arms.py with, on its last link, a palm (fixed joint),
two fingers (a revolute one with a fixed tip, a prismatic one) and, on link 2, a camera on a joint whose
limits admit one position (how uuv_simulator writes its sensors' joints). The system file locks the
fingers in ``[arm.lock]`` and ends the chain at the palm with a tool offset (docs/system-file.md form 3).

The reference is Pinocchio built from the whole URDF (tests/pinocchio_urdf.py: every joint a joint,
nothing reduced) with the fingers and the camera held at their positions (zero velocity and
acceleration): the arm's wrench on the vehicle, in dry conditions, from arvcas's model (the plant
function evaluated by CasADi, nothing compiled) must equal it to 1e-9. So the lock (arvcas uses
Pinocchio's ``buildReducedModel``) is checked against the unreduced tree.
"""

from __future__ import annotations

import copy
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

import arvcas
import pinocchio_urdf as pu
import urdf_arms as ua
from arvcas.model.uvms import plant_functions
from arvcas.system import urdf

RTOL = 1e-9
LOCKS = {"finger_l": 0.4, "finger_r": 0.012}  # rad, m
OFFSET = np.array([0.02, -0.01, 0.11])  # the tool point in the palm's frame


def _inertial(rng, name, m):
    return ua.LinkSpec(name, m, rng.uniform(-0.03, 0.03, 3), rng.uniform(-np.pi, np.pi, 3),
                       ua.realisable_inertia(rng, 0.002 * m))


def gripper_arm() -> ua.RandomArm:
    rng = np.random.default_rng(2323)
    arm = copy.deepcopy(ua.case_arm(4, "plain"))
    J = ua.JointSpec
    arm.links += [_inertial(rng, "palm", 0.6), _inertial(rng, "finger_l", 0.15), _inertial(rng, "finger_l_tip", 0.05),
                  _inertial(rng, "finger_r", 0.2), _inertial(rng, "camera", 0.3)]
    arm.joints += [
        J("palm_joint", "fixed", "link4", "palm", rng.uniform(-0.1, 0.1, 3), rng.uniform(-np.pi, np.pi, 3)),
        J("finger_l", "revolute", "palm", "finger_l", np.array([0.0, 0.03, 0.08]), np.array([0.0, 0.0, 0.3]),
          np.array([1.0, 0.0, 0.0]), -0.2, 1.1),
        J("finger_l_tip_joint", "fixed", "finger_l", "finger_l_tip", np.array([0.0, 0.0, 0.05]), np.zeros(3)),
        J("finger_r", "prismatic", "palm", "finger_r", np.array([0.0, -0.03, 0.08]), np.zeros(3),
          np.array([0.0, 1.0, 0.0]), -0.03, 0.03),
        J("camera_joint", "revolute", "link2", "camera", np.array([0.05, 0.0, 0.02]), np.array([0.0, 0.4, 0.0]),
          np.array([0.0, 0.0, 1.0]), 0.25, 0.25),
    ]
    arm.tool_link = "palm"
    for name in ("palm", "finger_l", "finger_l_tip", "finger_r"):
        arm.hydro_links[name] = dict(volume=rng.uniform(1e-5, 1e-4), cob=rng.uniform(-0.02, 0.02, 3),
                                     drag_diameter=0.0, drag_from=np.zeros(3), drag_to=np.zeros(3))
    arm.system_name = "gripper_arm"
    return arm


def system_text(arm: ua.RandomArm, locks=LOCKS) -> str:
    text = arm.system_toml()
    text = text.replace('tool_link = "palm"\n', 'tool_link = "palm"\ntool_offset = { value = [' +
                        ", ".join(repr(float(x)) for x in OFFSET) + '], unit = "m", source = "test" }\n')
    # the fingers' hydro entries: a volume and a centre of buoyancy only (no drag segment)
    for name, h in arm.hydro_links.items():
        if h["drag_diameter"] == 0.0:
            start = text.index(f"[arm.hydro.{name}]")
            end = text.index("\n\n", start)
            text = text[:start] + "\n".join(
                [f"[arm.hydro.{name}]", f"volume = {{ value = {h['volume']!r}, unit = \"m^3\", source = \"test\" }}",
                 f"cob = {{ value = [{', '.join(repr(float(x)) for x in h['cob'])}], unit = \"m\", source = \"test\" }}"]
            ) + text[end:]
    if locks:
        text += "\n[arm.lock]\n" + "".join(
            f'{k} = {{ value = {v!r}, unit = "{"m" if k == "finger_r" else "rad"}", source = "test" }}\n'
            for k, v in locks.items())
    return text


def _write(tmp_path, arm, text=None):
    (tmp_path / arm.urdf_name).write_text(arm.urdf)
    path = tmp_path / "gripper.toml"
    path.write_text(system_text(arm) if text is None else text)
    return path


@pytest.fixture(scope="module")
def loaded(tmp_path_factory):
    arm = gripper_arm()
    path = _write(tmp_path_factory.mktemp("gripper"), arm)
    return arm, arvcas.load_system(str(path))


def _reference(arm):
    """Pinocchio from the whole URDF (fingers and camera as joints), the tool point at the offset."""
    ref = pu.build_for(arm)
    full = pin.buildModelFromXML(arm.urdf)
    tool_point = full.frames[full.getFrameId("palm", pin.FrameType.BODY)].placement.act(OFFSET)
    held = {"finger_l": LOCKS["finger_l"], "finger_r": LOCKS["finger_r"], "camera_joint": 0.25}
    names = [ref.model.names[j] for j in ref.arm_joint_ids]
    return ref, names, held, tool_point


def _full(names, held, chain_values):
    it = iter(chain_values)
    return np.array([held[n] if n in held else next(it) for n in names])


def test_gripper_loads_with_fingers_locked(loaded):
    arm, system = loaded
    assert system.n_joints == 4
    v = dict(zip(system.params.names(), system.params.vector()))
    # the last body carries link 4, the palm and both fingers with the tip; link 2 the camera
    m = {lk.name: lk.mass for lk in arm.links}
    assert v["arm.link4.mass"] == pytest.approx(m["link4"] + m["palm"] + m["finger_l"] + m["finger_l_tip"]
                                                + m["finger_r"], rel=1e-12)
    assert v["arm.link2.mass"] == pytest.approx(m["link2"] + m["camera"], rel=1e-12)
    # buoyancy of the merged body: the volumes add, the centre is their volume-weighted mean
    full = pin.buildModelFromXML(arm.urdf)
    q = pin.neutral(full)
    for name, val in (("finger_l", LOCKS["finger_l"]), ("finger_r", LOCKS["finger_r"]), ("camera_joint", 0.25)):
        q[full.joints[full.getJointId(name)].idx_q] = val
    data = full.createData()
    pin.framesForwardKinematics(full, data, q)
    j4 = data.oMi[full.getJointId("joint4")]
    V, first = 0.0, np.zeros(3)
    for name in ("link4", "palm", "finger_l", "finger_l_tip", "finger_r"):
        h = arm.hydro_links[name]
        c = j4.actInv(data.oMf[full.getFrameId(name, pin.FrameType.BODY)].act(h["cob"]))
        V, first = V + h["volume"], first + h["volume"] * c
    assert v["arm.link4.volume"] == pytest.approx(V, rel=1e-12)
    got = np.array([v[f"arm.link4.cob.{c}"] for c in "xyz"])
    np.testing.assert_allclose(got, first / V, rtol=0, atol=1e-14)
    # the tool point: the offset in the palm's frame, in joint 4's frame
    tool = np.array([v[f"arm.tool.{c}"] for c in "xyz"])
    np.testing.assert_allclose(j4.actInv(data.oMf[full.getFrameId("palm", pin.FrameType.BODY)].act(OFFSET)), tool, rtol=0, atol=1e-14)


def test_gripper_arm_matches_unreduced_pinocchio(loaded):
    arm, system = loaded
    ref, names, held, tool_point = _reference(arm)
    hydro = [k for k in system.params.names() if k.startswith("hydro.")]
    p = system.params.replace({"env.rho": 0.0, **{k: 0.0 for k in hydro}}).vector()
    f = plant_functions(layout=system.layout)["arm_wrench"]
    rng = np.random.default_rng(5)
    worst = 0.0
    for k in range(6):
        eta, nu, nud, q, qd, qdd = pu.random_state(rng, arm.qmin, arm.qmax)
        payload = (0.0, 0.5, 1.0)[k % 3]
        got = np.array(f(eta, nu, nud, q, qd, qdd, payload, p)).ravel()
        zero = {n: 0.0 for n in held}
        want = pu.arm_wrench_on_vehicle(ref, eta, nu, nud, _full(names, held, q), _full(names, zero, qd),
                                        _full(names, zero, qdd), payload_mass=payload * arm.payload_mass,
                                        tool_point=tool_point)
        worst = max(worst, float(np.linalg.norm(got - want) / np.linalg.norm(want)))
    print(f"gripper arm: arm_wrench against the unreduced Pinocchio tree, max relative error {worst:.2e}")
    assert worst < RTOL


def test_arm_base_mass_reported():
    """What is rigid on the base link (here the base link alone) is reported, not put in the arm."""
    arm = gripper_arm()
    base = next(lk for lk in arm.links if lk.name == "base_link")
    assert base.mass is None  # the random arms' base link has no inertial
    root = ET.fromstring(arm.urdf)
    link = next(e for e in root.findall("link") if e.get("name") == "base_link")
    link.append(ET.fromstring('<inertial><origin xyz="0.1 0 0.2" rpy="0 0 0"/><mass value="2.5"/>'
                              '<inertia ixx="0.01" iyy="0.02" izz="0.015" ixy="0" ixz="0" iyz="0"/></inertial>'))
    locks = {"finger_l": (0.4, "test"), "finger_r": (0.012, "test")}
    got = urdf.arm_chain(root, "base_link", "palm", "arm.urdf", "arm.urdf", ValueError, locks=locks)
    assert got.joints == ("joint1", "joint2", "joint3", "joint4")
    assert got.base_mass == 2.5
    np.testing.assert_allclose(got.base_com, [0.1, 0.0, 0.2], atol=1e-15)
    assert set(got.locked) == {"finger_l", "finger_r", "camera_joint"} and got.locked["camera_joint"] == 0.25


@pytest.mark.parametrize("fault,words", [
    ("unlocked", ["finger_l", "branch", "[arm.lock]"]),
    ("outside", ["arm.lock.finger_l", "outside", "limits"]),
    ("unknown", ["arm.lock.finger_x", "no joint", "did you mean"]),
])
def test_gripper_faults_refused(tmp_path, fault, words):
    arm = gripper_arm()
    locks = dict(LOCKS)
    if fault == "unlocked":
        locks.pop("finger_l")
    elif fault == "outside":
        locks["finger_l"] = 2.0
    else:
        locks["finger_x"] = locks.pop("finger_l")
    path = _write(tmp_path, arm, system_text(arm, locks))
    with pytest.raises(ValueError) as ei:
        arvcas.load_system(str(path))
    msg = str(ei.value)
    assert "\n" not in msg and all(w in msg for w in words), msg
