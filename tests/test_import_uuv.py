"""`arvcas import-system uuv` on uuv_simulator's public RexROV 2 (+ Oberon 7) description.

The description is the excerpt in tests/data/uuv_rexrov2/ (its README: sources, commits, the licence,
the one change). The references are independent of arvcas's importer:

- xacro expands the description here with its own ``$(find)`` resolver;
- uuv_simulator's thruster manager's own allocation matrix (``TAM.yaml``, computed by ROS tf in the
  description's FLU frame): the imported system's B must equal ``blkdiag(T, T) TAM`` to 1e-6,
  ``T = diag(1, -1, -1)``;
- Pinocchio reads the expanded URDF as it is (FLU, gravity along -z, every joint a joint): the
  imported vehicle's M_RB equals its composite inertia turned into FRD, and, in dry conditions, arvcas's
  coupled vehicle + arm accelerations (``uvms_rhs``, evaluated by CasADi, nothing compiled) equal
  Pinocchio's forward dynamics with the arm's accelerations prescribed and the fingers held, turned
  into FRD;
- uuv_simulator's Fossen plugin's force law written out here from HydrodynamicModel.cc (velocity turned
  "ToNED", ``-Ma a - Ca(v) v - D(v) v``, the force turned back): equal to arvcas's hydrodynamic forces.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

xacro = pytest.importorskip("xacro")
yaml = pytest.importorskip("yaml")
pin = pytest.importorskip("pinocchio")

import arvcas  # noqa: E402
from arvcas.cli import main  # noqa: E402
from arvcas.model import thrusters, vehicle  # noqa: E402
from arvcas.model.uvms import plant_functions  # noqa: E402
from arvcas.system import uuv  # noqa: E402
from arvcas.system.params import view  # noqa: E402

DATA = Path(__file__).parent / "data" / "uuv_rexrov2"
ROBOTS = DATA / "rexrov2_description" / "robots"
TM = DATA / "rexrov2_control" / "config" / "thruster_manager.yaml"
TAM = DATA / "rexrov2_control" / "config" / "TAM.yaml"
T = np.diag([1.0, -1.0, -1.0])
T6 = np.kron(np.eye(2), T)
FINGERS = {"oberon7/finger_left_joint": 0.3, "oberon7/finger_right_joint": 0.5}


def _expand(name: str) -> str:
    """The URDF of a robot file of the excerpt, by xacro, ``$(find pkg)`` = the excerpt's folder ``pkg``."""
    from xacro import substitution_args as sa

    old = sa._eval_find, sa._eval_dict["find"]
    find = lambda pkg: str((DATA / pkg).resolve())  # noqa: E731
    sa._eval_find = sa._eval_dict["find"] = find
    try:
        xacro.init_stacks(None)
        return xacro.process_file(str((ROBOTS / name).resolve()), verbosity=0).toxml()
    finally:
        sa._eval_find, sa._eval_dict["find"] = old


def _values(system) -> dict:
    return dict(zip(system.params.names(), system.params.vector()))


@pytest.fixture(scope="module")
def rexrov2(tmp_path_factory):
    imp = uuv.import_uuv(ROBOTS / "rexrov2_default.xacro", ros_paths=[DATA], thruster_manager=TM)
    path = tmp_path_factory.mktemp("rexrov2") / "rexrov2.toml"
    path.write_text(imp.text)
    return imp, arvcas.load_system(str(path)), _expand("rexrov2_default.xacro")


@pytest.fixture(scope="module")
def oberon7(tmp_path_factory):
    imp = uuv.import_uuv(ROBOTS / "rexrov2_oberon7.xacro", ros_paths=[DATA], thruster_manager=TM,
                         arm_base="oberon7/base", tool_link="oberon7/end_effector",
                         locks={k: (v, "test") for k, v in FINGERS.items()})
    path = tmp_path_factory.mktemp("oberon7") / "rexrov2_oberon7.toml"
    path.write_text(imp.text)
    return imp, arvcas.load_system(str(path)), _expand("rexrov2_oberon7.xacro")


def test_allocation_matrix_is_uuv_simulators_tam(rexrov2):
    imp, system, _ = rexrov2
    tam = np.array(yaml.safe_load(TAM.read_text())["tam"], dtype=float)
    B = np.array(thrusters.B_T(view(system.params.vector(), system.layout)), dtype=float)
    err = float(np.abs(B - T6 @ tam).max())
    print(f"RexROV2: |B - blkdiag(T, T) TAM|max = {err:.3g} (columns {', '.join(imp.thrusters)})")
    assert B.shape == tam.shape == (6, 6)
    assert err < 1e-6
    v = _values(system)
    assert all(v[f"thrusters.thruster_{k}.u_max"] == 1540.0 == -v[f"thrusters.thruster_{k}.u_min"] for k in range(6))


def test_mass_matrices_after_the_frame_change(rexrov2):
    """M_RB: Pinocchio's composite inertia of the URDF's bodies (free flyer at its origin, every joint at
    zero) in FLU, turned into FRD; M_A: the plugin's <added_mass> as written (the plugin applies it to
    the velocity turned into FRD)."""
    _, system, text = rexrov2
    P = view(system.params.vector(), system.layout)
    model = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
    data = model.createData()
    M_flu = pin.crba(model, data, pin.neutral(model))[:6, :6]
    M_flu = np.triu(M_flu) + np.triu(M_flu, 1).T
    M_RB = np.array(vehicle.M_RB(P), dtype=float)
    rel = float(np.abs(M_RB - T6 @ M_flu @ T6).max() / np.abs(M_flu).max())
    print(f"RexROV2: M_RB against Pinocchio's composite inertia in FRD: {rel:.2e} relative; "
          f"m = {M_RB[0, 0]:.6f} kg")
    assert rel < 1e-13
    assert M_RB[0, 0] == pytest.approx(1862.87 + 6 * 0.001, rel=1e-15)  # base link + six propellers
    raw = re.search(r"<added_mass>(.*?)</added_mass>", (DATA / "rexrov2_description/urdf/rexrov2.gazebo.xacro")
                    .read_text(), re.S).group(1)
    Ma = np.array(raw.split(), dtype=float).reshape(6, 6)
    np.testing.assert_array_equal(np.array(vehicle.M_A(P), dtype=float), Ma)
    # the same matrix seen from the description's FLU frame
    np.testing.assert_array_equal(T6 @ np.array(vehicle.M_A(P), dtype=float) @ T6, T6 @ Ma @ T6)


def _skew(a):
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


def _plugin_force(Ma, Dlin, Dquad, nu_flu, acc_flu, Ma_coriolis=None):
    """HMFossen::ApplyHydrodynamicForces (uuv_simulator HydrodynamicModel.cc), no current, exact acceleration:
    v = ToNED(nu) (y, z negated), D = -Dlin - diag(Dquad) |v|, Ca from Ma v (Fossen eq. 6.43), the force
    -D v - Ma a - Ca v, turned back FromNED (``Ma_coriolis``: another matrix for Ca). The force in FLU."""
    v, a = T6 @ nu_flu, T6 @ acc_flu
    D = -Dlin - np.diag(np.diag(Dquad) * np.abs(v))
    ab = (Ma if Ma_coriolis is None else Ma_coriolis) @ v
    Sa = -_skew(ab[:3])
    Ca = np.block([[np.zeros((3, 3)), Sa], [Sa, -_skew(ab[3:])]])
    return T6 @ (-D @ v - Ma @ a - Ca @ v)


def test_hydrodynamic_forces_are_the_plugins(rexrov2):
    _, system, text = rexrov2
    P = view(system.params.vector(), system.layout)
    root = ET.fromstring(text)
    blk = next(lk for pl in root.iter("plugin") for lk in pl.findall("link") if lk.get("name") == "rexrov2/base_link")
    hm = blk.find("hydrodynamic_model")
    Ma = np.array(hm.findtext("added_mass").split(), dtype=float).reshape(6, 6)
    Dlin = np.diag(np.array(hm.findtext("linear_damping").split(), dtype=float))
    Dquad = np.diag(np.array(hm.findtext("quadratic_damping").split(), dtype=float))
    rng = np.random.default_rng(23)
    worst = worst_raw = 0.0
    for _ in range(20):
        nu_flu, acc_flu = rng.normal(size=6), rng.normal(size=6)
        nu, acc = T6 @ nu_flu, T6 @ acc_flu
        f = -np.array(vehicle.M_A(P), float) @ acc - np.array(vehicle.C_A(P, nu) @ nu + vehicle.D(P, nu) @ nu,
                                                                float).ravel()
        want = _plugin_force(Ma, Dlin, Dquad, nu_flu, acc_flu, 0.5 * (Ma + Ma.T))  # arvcas's C_A: symmetric part
        raw = _plugin_force(Ma, Dlin, Dquad, nu_flu, acc_flu)
        worst = max(worst, float(np.linalg.norm(T6 @ f - want) / np.linalg.norm(want)))
        worst_raw = max(worst_raw, float(np.linalg.norm(T6 @ f - raw) / np.linalg.norm(raw)))
    print(f"RexROV2 hydrodynamic force vs the plugin's: {worst:.2e} (C_A of sym(M_A)), {worst_raw:.2e} "
          f"(the plugin's C_A of M_A as written, asymmetric by 0.001)")
    assert worst < 1e-12 and worst_raw < 1e-5


def test_restoring_forces_are_gazebos(rexrov2):
    """Weight at the URDF's centre of mass (Pinocchio) and the plugin's buoyancy rho g V (world up) at its
    <center_of_buoyancy> in the link frame, in FLU, turned into FRD: arvcas's -g(eta)."""
    _, system, text = rexrov2
    P = view(system.params.vector(), system.layout)
    v = _values(system)
    model = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
    data = model.createData()
    q0 = pin.neutral(model)
    m, c = pin.computeTotalMass(model), pin.centerOfMass(model, data, q0)
    blk = next(lk for pl in ET.fromstring(text).iter("plugin") for lk in pl.findall("link")
               if lk.get("name") == "rexrov2/base_link")
    V, cob = float(blk.findtext("volume")), np.array(blk.findtext("center_of_buoyancy").split(), dtype=float)
    rho = float(next(ET.fromstring(text).iter("fluid_density")).text)
    g = v["env.g"]
    rng = np.random.default_rng(3)
    for _ in range(10):
        eta = np.concatenate([np.zeros(3), rng.uniform(-1, 1, 2), rng.uniform(-3, 3, 1)])
        R = T @ _rzyx(*eta[3:]) @ T  # body FLU -> world z up
        fg, fb = R.T @ [0.0, 0.0, -m * g], R.T @ [0.0, 0.0, rho * g * V]
        w = np.concatenate([fg + fb, np.cross(c, fg) + np.cross(cob, fb)])
        got = -np.array(vehicle.g_vec(P, eta), dtype=float).ravel()
        np.testing.assert_allclose(got, T6 @ w, rtol=0, atol=1e-12 * m * g)


def _rzyx(phi, theta, psi):
    c, s = np.cos, np.sin
    Rx = np.array([[1, 0, 0], [0, c(phi), -s(phi)], [0, s(phi), c(phi)]])
    Ry = np.array([[c(theta), 0, s(theta)], [0, 1, 0], [-s(theta), 0, c(theta)]])
    Rz = np.array([[c(psi), -s(psi), 0], [s(psi), c(psi), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _pinocchio_accel(text, g, eta, nu, arm, q, qd, qdd, tau):
    """nu_dot (FRD) of the whole URDF in Pinocchio, FLU: world z up (gravity -g z), base R_flu = T R T,
    velocities T6 nu; arm joints ``arm`` at q, qd, qdd; fingers held at FINGERS; every other joint at 0."""
    model = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
    model.gravity.linear = np.array([0.0, 0.0, -g])
    data = model.createData()
    R = T @ _rzyx(*eta[3:]) @ T
    cfg, v, a = pin.neutral(model), np.zeros(model.nv), np.zeros(model.nv)
    cfg[:3] = T @ eta[:3]
    cfg[3:7] = pin.Quaternion(R).coeffs()
    v[:6] = T6 @ nu
    for k, name in enumerate(arm):
        j = model.joints[model.getJointId(name)]
        assert j.nq == 1
        cfg[j.idx_q], v[j.idx_v], a[j.idx_v] = q[k], qd[k], qdd[k]
    for name, val in FINGERS.items():
        if model.existJointName(name):
            cfg[model.joints[model.getJointId(name)].idx_q] = val
    b = pin.rnea(model, data, cfg, v, a)[:6]
    M = pin.crba(model, data, cfg)
    M = np.triu(M) + np.triu(M, 1).T
    return T6 @ np.linalg.solve(M[:6, :6], T6 @ tau - b)


@pytest.mark.parametrize("which", ["rexrov2", "oberon7"])
def test_dry_dynamics_match_pinocchio_on_the_urdf(which, request):
    """rho = 0 and every [hydro] term zero: nothing but rigid bodies under gravity; arvcas's uvms_rhs (the
    arm's trim off, as written by the import) against Pinocchio on the URDF as uuv_simulator wrote it."""
    imp, system, text = request.getfixturevalue(which)
    hydro = [k for k in system.params.names() if k.startswith("hydro.")]
    p = system.params.replace({"env.rho": 0.0, **{k: 0.0 for k in hydro}}).vector()
    v = _values(system)
    n = system.n_joints
    names = imp.arm_joints
    assert len(names) == n
    f = plant_functions(layout=system.layout)["uvms_rhs"]
    rng = np.random.default_rng(7)
    qmin = np.array([v[f"arm.joint{i}.qmin"] for i in range(1, n + 1)])
    qmax = np.array([v[f"arm.joint{i}.qmax"] for i in range(1, n + 1)])
    worst = 0.0
    for _ in range(5):
        eta = np.concatenate([rng.normal(size=3), rng.uniform(-1, 1, 2), rng.uniform(-3, 3, 1)])
        nu, tau = rng.normal(size=6) * 0.5, 2000 * rng.normal(size=6)
        q, qd, qdd = rng.uniform(qmin, qmax), rng.normal(size=n), rng.normal(size=n)
        got = np.array(f(np.concatenate([eta, nu]), tau, q, qd, qdd, 0.0, p)).ravel()[6:]
        want = _pinocchio_accel(text, v["env.g"], eta, nu, names, q, qd, qdd, tau)
        worst = max(worst, float(np.linalg.norm(got - want) / np.linalg.norm(want)))
    print(f"{which}: uvms_rhs (dry) against Pinocchio on the FLU URDF, max relative error {worst:.2e}")
    assert worst < 1e-9


def test_oberon7_arm(oberon7):
    imp, system, text = oberon7
    assert system.n_joints == 6 and system.structure.arm_trim is False
    v = _values(system)
    root = ET.fromstring(text)
    mass = {lk.get("name"): float(lk.find("inertial/mass").get("value")) for lk in root.findall("link")
            if lk.find("inertial") is not None}
    # the vehicle carries the arm's base link (its weight and buoyancy); the last body the jaws
    assert v["vehicle.m"] == pytest.approx(mass["rexrov2/base_link"] + 6 * 0.001 + mass["oberon7/base"], rel=1e-15)
    jaws = [k for k in mass if k.startswith("oberon7/finger") or k == "oberon7/end_effector"]
    assert len(jaws) == 5
    assert v["arm.link6.mass"] == pytest.approx(sum(mass[k] for k in jaws), rel=1e-14)
    vol = {lk.get("name"): float(lk.findtext("volume")) for pl in root.iter("plugin") for lk in pl.findall("link")}
    assert v["vehicle.volume"] == pytest.approx(vol["rexrov2/base_link"] + vol["oberon7/base"], rel=1e-15)
    assert v["arm.link1.volume"] == vol["oberon7/shoulder_link"]
    # the mount: 1.3 m forward, 0.5 m to starboard, 0.665 m down; the arm's frame turned a half turn about x
    assert [v[f"arm.mount.{k}"] for k in ("x", "y", "z", "roll", "pitch", "yaw")] == pytest.approx(
        [1.3, 0.5, 0.665, np.pi, 0.0, 0.0], abs=1e-15)
    assert any("cylinder" in n for n in imp.notes) and not any("timeConstant" in n for n in imp.notes)


def test_cli_import(tmp_path, capsys):
    out = tmp_path / "rexrov2.toml"
    args = ["import-system", "uuv", str(DATA / "rexrov2_description"), "--out", str(out), "--ros-path", str(DATA),
            "--thruster-manager", str(TM), "--check-tam", str(TAM), "--cite", "uuvsimulator/rexrov2 @1546681"]
    assert main(args) == 0
    text = capsys.readouterr().out
    err = float(re.search(r"largest difference (\S+)", text).group(1))
    assert err < 1e-6, text
    doc = out.read_text()
    assert doc.count('source = "uuvsimulator/rexrov2 @1546681, rexrov2_description/robots/rexrov2_default.xacro') > 50
    assert 'map = "basic"' in doc and "<dynamics> FirstOrder <timeConstant>" in doc and "dynamics (" not in doc
    assert arvcas.load_system(str(out)).n_thrusters == 6
    assert main(args) == 0  # arvcas wrote it: replaced
    mine = tmp_path / "mine.toml"
    mine.write_text("# the user's\n")
    capsys.readouterr()
    assert main(args[:4] + [str(mine)] + args[5:]) == 2
    assert "not written by arvcas" in capsys.readouterr().err and mine.read_text() == "# the user's\n"


def _plugins(urdf: str) -> list:
    """The thruster plugins of an expanded URDF: (name, timeConstant, rotorConstant) as uuv_simulator reads them."""
    out = []
    for pl in ET.fromstring(urdf).iter("plugin"):
        if pl.get("filename") == "libuuv_thruster_ros_plugin.so":
            out.append((pl.get("name"), pl.findtext("dynamics/type"), float(pl.findtext("dynamics/timeConstant")),
                        pl.findtext("conversion/type"), float(pl.findtext("conversion/rotorConstant"))))
    return out


def test_thruster_dynamics_are_uuv_simulators(rexrov2):
    """Each imported thruster's lag and rotor law are its plugin's (ThrusterPlugin.cc with FirstOrder and Basic,
    written out here): for rotor speeds w the thrust is rotorConstant * |w| * w, and over a step dt the rotor
    follows ``state = state * exp(-dt / timeConstant) + (1 - exp(-dt / timeConstant)) * cmd``."""
    import casadi as ca

    imp, system, urdf = rexrov2
    P = view(system.params)
    st = system.params.structure
    plugins = _plugins(urdf)
    assert [(d, c) for _, d, _, c, _ in plugins] == [("FirstOrder", "Basic")] * 6 and st.has_thruster_dynamics
    w = np.array([-240.0, -97.3, -1.5, 0.0, 0.25, 12.0, 180.0, 240.0])  # rad/s, within the command range
    for name, (_, _, tc, _, rc) in zip(st.thrusters, plugins):
        assert P[f"thrusters.{name}.time_constant"] == tc == 0.05  # the xacro's dyn_time_constant
        m = st.thruster_map(st.thruster_dynamics[st.thrusters.index(name)].map)
        assert m.kind == "quadratic" and m.unit == "rad/s"
        T = np.array(ca.DM(thrusters.map_thrust(P, m, ca.DM(w)))).ravel()
        np.testing.assert_allclose(T, rc * np.abs(w) * w, rtol=1e-15, atol=0)
        lo, hi = float(P[f"thrusters.map.{m.name}.command_min"]), float(P[f"thrusters.map.{m.name}.command_max"])
        assert rc * hi * hi >= float(P[f"thrusters.{name}.u_max"]) == 1540.0 and lo == -hi  # covers the limits
    # the lag over dt = 0.01 s from a spinning rotor to a new command, against the plugin's update
    dt, s0, cmd = 0.01, ca.DM([50.0, -20.0, 0.0, 200.0, -240.0, 1.0]), ca.DM([-100.0, 30.0, 80.0, 200.0, 0.0, 1.0])
    E = thrusters.lag_constants(P, [dt])
    s1 = np.array(ca.DM(ca.vertcat(*[row[0] for row in thrusters.lag_states(P, s0, cmd, E, [dt], dt)]))).ravel()
    a = np.exp(-dt / 0.05)
    np.testing.assert_allclose(s1, np.array(s0).ravel() * a + (1 - a) * np.array(cmd).ravel(), rtol=1e-14, atol=1e-12)


def _variant(tmp_path, old: str, new: str) -> Path:
    """A copy of the excerpt with one text replaced in uuv_simulator's thruster snippets."""
    import shutil

    root = tmp_path / "data"
    shutil.copytree(DATA, root)
    f = root / "uuv_gazebo_ros_plugins" / "urdf" / "thruster_snippets.xacro"
    text = f.read_text()
    assert old in text
    f.write_text(text.replace(old, new, 1))
    return root


@pytest.mark.parametrize("old,new,words", [
    ("<type>FirstOrder</type>", "<type>Yoerger</type>", ["<dynamics> <type> 'Yoerger'", "ZeroOrder or FirstOrder"]),
    ("<type>Basic</type>", "<type>Bessa</type>", ["<conversion> <type> 'Bessa'", "Basic"]),
    ("<timeConstant>${time_constant}</timeConstant>", "<timeConstant>0</timeConstant>",
     ["<timeConstant> must be > 0"]),
])
def test_cli_refuses_thruster_models_arvcas_cannot_represent(tmp_path, capsys, old, new, words):
    root = _variant(tmp_path, old, new)
    out = tmp_path / "x.toml"
    code = main(["import-system", "uuv", str(root / "rexrov2_description"), "--out", str(out), "--ros-path", str(root),
                 "--thruster-manager", str(TM)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not out.exists() and "\n" not in err, err
    assert "rexrov2_default.xacro" in err and "rexrov2_0_thruster_model" in err and all(w in err for w in words), err


def test_gain_clamps_and_efficiencies_fold_into_the_map(tmp_path):
    """ThrusterPlugin.cc: x = gain * clamp(input), thrust = thrust_efficiency * convert(propeller_efficiency * lag(x)):
    the rotor law's constant is thrust_efficiency * propeller_efficiency^2 * rotorConstant, the command range
    gain * [clampMin, clampMax]."""
    tag = "<thrusterID>${thruster_id}</thrusterID>"
    root = _variant(tmp_path, tag, tag + "<gain>2</gain><clampMin>-1000</clampMin><clampMax>1000</clampMax>"
                                      "<thrust_efficiency>0.5</thrust_efficiency><propeller_efficiency>0.8"
                                      "</propeller_efficiency>")
    imp = uuv.import_uuv(root / "rexrov2_description" / "robots" / "rexrov2_default.xacro", ros_paths=[root],
                         thruster_manager=TM)
    path = tmp_path / "r.toml"
    path.write_text(imp.text)
    v = _values(arvcas.load_system(str(path)))
    assert v["thrusters.map.basic.rotor_constant"] == pytest.approx(0.5 * 0.8 ** 2 * 0.026546960744430276, rel=1e-15)
    assert (v["thrusters.map.basic.command_min"], v["thrusters.map.basic.command_max"]) == (-2000.0, 2000.0)


def test_zero_order_thrusters_are_instantaneous(tmp_path):
    root = _variant(tmp_path, "<type>FirstOrder</type>", "<type>ZeroOrder</type>")
    imp = uuv.import_uuv(root / "rexrov2_description" / "robots" / "rexrov2_default.xacro", ros_paths=[root],
                         thruster_manager=TM)
    assert "time_constant" not in imp.text and "[thrusters.map" not in imp.text
    assert any("ZeroOrder" in n and "Basic" in n for n in imp.notes)


@pytest.mark.parametrize("extra,words", [
    ([], ["thrustMin/thrustMax", "--thruster-manager", "--max-thrust"]),
    (["--max-thrust", "1540", "--arm-base", "oberon7/base"], ["--arm-base and --tool-link go together"]),
    (["--max-thrust", "1540", "--lock", "nope=1"], ["--lock nope", "no joint"]),
    (["--max-thrust", "-3"], ["--max-thrust", "positive"]),
    (["--max-thrust", "1540", "--stow", "0,1"], ["--stow", "only with --arm-base"]),
    (["--max-thrust", "1540", "--thruster-manager", str(TM)], ["given twice"]),
])
def test_cli_refusals(tmp_path, capsys, extra, words):
    out = tmp_path / "x.toml"
    code = main(["import-system", "uuv", str(ROBOTS / "rexrov2_default.xacro"), "--out", str(out), "--ros-path",
                 str(DATA), *extra])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not out.exists() and "\n" not in err and all(w in err for w in words), err


def test_cli_bad_descriptions(tmp_path, capsys):
    (tmp_path / "robots").mkdir()
    for name in ("a.xacro", "b.xacro"):
        (tmp_path / "robots" / name).write_text("<robot/>")
    (tmp_path / "no_plugin.urdf").write_text('<robot name="r"><link name="base"/></robot>')
    for desc, words in ((tmp_path / "nope.urdf", ["nope.urdf", "not found"]),
                        (tmp_path, ["a folder", "a.xacro, b.xacro"]),
                        (tmp_path / "no_plugin.urdf", ["'base'", "underwater-object plugin"])):
        code = main(["import-system", "uuv", str(desc), "--out", str(tmp_path / "x.toml"), "--max-thrust", "9"])
        err = capsys.readouterr().err.strip()
        assert code == 2 and "\n" not in err and all(w in err for w in words), err


def test_cli_finger_not_locked(tmp_path, capsys):
    code = main(["import-system", "uuv", str(ROBOTS / "rexrov2_oberon7.xacro"), "--out", str(tmp_path / "x.toml"),
                 "--ros-path", str(DATA), "--max-thrust", "1540", "--arm-base", "oberon7/base", "--tool-link",
                 "oberon7/end_effector"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "oberon7/finger_left_joint" in err and "--lock" in err, err
