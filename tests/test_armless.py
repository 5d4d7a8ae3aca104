"""The vehicles users fly: the shipped BlueROV2 (six T200s, ArduSub's vectored frame) and BlueROV2 Heavy
(eight T200s) without an arm, and what a system without an arm needs (no ``[arm]`` anywhere).

References independent of the code under test: ArduSub's motor factors (ArduPilot/ardupilot @0fd5fbf
libraries/AP_Motors/AP_Motors6DOF.cpp, ``setup_motors``: numbers, written out below), the von Benzon
geometry of the shipped Heavy + Alpha 5, NumPy's pseudo-inverse for the minimum-norm allocation, SciPy's
PchipInterpolator for a table with saturation plateaus. Refusals are checked to come before any compile
by making every compile raise.
"""

from __future__ import annotations

import re
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import arvcas
from arvcas import cli
from arvcas.ident import logs, plant, validate
from arvcas.model import thrusters
from arvcas.sim import limits, profiles, scenario
from arvcas.system.params import ParamsError, load, view

# ArduSub's factors (roll, pitch, yaw, throttle, forward, lateral) per motor, AP_Motors6DOF.cpp @0fd5fbf
VECTORED = [(0, 0, 1, 0, -1, 1), (0, 0, -1, 0, -1, -1), (0, 0, -1, 0, 1, 1), (0, 0, 1, 0, 1, -1),
            (1, 0, 0, -1, 0, 0), (-1, 0, 0, -1, 0, 0)]
VECTORED_6DOF = VECTORED[:4] + [(1, -1, 0, -1, 0, 0), (-1, -1, 0, -1, 0, 0), (1, 1, 0, -1, 0, 0),
                                (-1, 1, 0, -1, 0, 0)]


def _B(system) -> np.ndarray:
    return np.array(ca.evalf(thrusters.B_T(view(ca.DM(system.params.vector()), system.layout))), dtype=float)


@pytest.mark.parametrize("name, factors", [("bluerov2", VECTORED), ("bluerov2_heavy", VECTORED_6DOF)])
def test_thrusters_follow_ardusub_motor_order(name, factors):
    """Thruster Tn is ArduSub's motor n: its force along the signs of (forward, lateral, -throttle), its
    moment with the signs of every non-zero roll, pitch and yaw factor; nothing where a factor is 0 but
    the thrusters' small lever arms (the horizontals' 0.085 m below the CG)."""
    s = arvcas.load_system(name)
    assert s.structure.thrusters == tuple(f"T{i}" for i in range(1, len(factors) + 1))
    assert s.n_joints == 0
    B = _B(s)
    for i, (R, P, Y, T, F, L) in enumerate(factors):
        force, moment = B[:3, i], B[3:, i]
        np.testing.assert_array_equal(np.sign(np.round(force, 12)), np.sign([F, L, -T]), err_msg=f"T{i + 1}")
        for k, fac in enumerate((R, P, Y)):
            if fac:
                assert np.sign(moment[k]) == fac, (name, i + 1, k)
        assert np.isclose(np.linalg.norm(force), 1.0)


def test_heavy_is_von_benzons_heavy_in_ardusub_sense():
    """The same eight lines of force as the Heavy + Alpha 5 (von Benzon's geometry), pushed the other way:
    ArduSub's positive output is von Benzon's negative, motor for motor."""
    np.testing.assert_allclose(_B(arvcas.load_system("bluerov2_heavy")),
                               -_B(arvcas.load_system("bluerov2_heavy_alpha5")), atol=1e-15)
    six, heavy = (arvcas.load_system(n).params for n in ("bluerov2", "bluerov2_heavy"))
    for n in heavy.names():  # the hull and T1-T4 are the Heavy's; T5, T6 sit on the pitch axis
        if not n.startswith(("thrusters.T5.position", "thrusters.T6.position", "thrusters.T7", "thrusters.T8")):
            assert six[n] == heavy[n], n
    assert six["thrusters.T5.position.x"] == six["thrusters.T6.position.x"] == 0.0  # on the pitch axis
    assert "env.Cd" not in heavy.names() and not any(n.startswith(("arm.", "payload.")) for n in heavy.names())


def test_unactuated_pitch_allocation_is_minimum_norm():
    s = arvcas.load_system("bluerov2")
    assert s.structure.unactuated == (4,)
    B = _B(s)
    assert np.linalg.matrix_rank(B) == 5
    np.testing.assert_allclose(B[4], 0.085 * B[0], atol=1e-15)  # pitch row = 0.085 m x surge row
    P = view(ca.DM(s.params.vector()), s.layout)
    rows = [0, 1, 2, 3, 5]
    rng = np.random.default_rng(1)
    for _ in range(5):
        tau = rng.normal(0, 10, 6)
        u = np.array(ca.evalf(thrusters.allocate(P, ca.DM(tau)))).ravel()
        np.testing.assert_allclose(u, np.linalg.pinv(B[rows]) @ tau[rows], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose((B @ u)[rows], tau[rows], atol=1e-12)
    lo, hi = thrusters.envelope(view(s.params.vector(), s.layout))
    assert lo[4] == hi[4] == 0.0
    np.testing.assert_allclose(hi, [85.98, 77.97, 60.8, 6.627, 0.0, 22.96], rtol=2e-3)  # docs/systems/bluerov2.md §4
    np.testing.assert_allclose(lo, hi, rtol=1e-12)


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace('unactuated = ["pitch"]', ''),
     r'thruster allocation matrix B has rank 5, not 6 .*unactuated = \["pitch"\]'),
    (lambda t: t.replace('unactuated = ["pitch"]', 'unactuated = ["pich"]'),
     r"thrusters\.unactuated: 'pich' is not a degree of freedom .*did you mean 'pitch'"),
    (lambda t: t.replace('unactuated = ["pitch"]', 'unactuated = ["roll"]'),
     r"allocation matrix B has rank 4, not 5"),
])
def test_unactuated_refusals(tmp_path, edit, match):
    src = arvcas.load_system("bluerov2").path
    text = edit(open(src, encoding="utf-8").read())
    p = tmp_path / "bluerov2.toml"
    p.write_text(text.replace('table = "t200_16v.csv"', 'table = "t200_16v.csv"'))
    with pytest.raises(ParamsError, match=match) as e:
        load(p)
    assert "\n" not in str(e.value)


# ---- a measured thrust table with saturation plateaus ---------------------------------------------------


def _plateau_system(tmp_path, head: int = 3, tail: int = 4, u_max: str | None = None, middle: bool = False):
    src = arvcas.load_system("bluerov2_heavy").path
    csv = (Path(src).parent / "t200_16v.csv").read_text().splitlines()
    rows = [r for r in csv if r and r[0].isdigit()]
    c0, t0 = rows[0].split(",")
    c1, t1 = rows[-1].split(",")
    pre = [f"{int(c0) - 4 * k},{t0}" for k in range(head, 0, -1)]  # the ends held flat: 1088-1096, 1904-1916 us
    post = [f"{int(c1) + 4 * k},{t1}" for k in range(1, tail + 1)]
    if middle:  # a flat stretch inside the forward range
        i = next(j for j, r in enumerate(rows) if r.startswith("1700,"))
        rows[i + 1] = rows[i + 1].split(",")[0] + "," + rows[i].split(",")[1]
    body = [r for r in csv if not (r and r[0].isdigit())] + pre + rows + post
    (tmp_path / "t200_plateau.csv").write_text("\n".join(body) + "\n")
    text = open(src, encoding="utf-8").read().replace('table = "t200_16v.csv"', 'table = "t200_plateau.csv"')
    text = text.replace('[defaults]\nscenario = "bluerov2.scenario.toml"\ngains = "bluerov2_heavy_alpha5.gains.toml"\n', "")
    if u_max is not None:
        text = re.sub(r'u_max = \{ value = 30\.4,', f"u_max = {{ value = {u_max},", text, count=1)
    p = tmp_path / "heavy_plateau.toml"
    p.write_text(text)
    return p


def test_thrust_table_with_saturation_plateaus(tmp_path):
    from scipy.interpolate import PchipInterpolator

    s = arvcas.load_system(_plateau_system(tmp_path))
    st = s.structure
    m = st.thruster_map("t200_16v")
    assert m.n == 201 + 3 + 4
    P = view(ca.DM(s.params.vector()), s.layout)
    g, v = (np.array(ca.evalf(x)).ravel() for x in thrusters.map_grid(P, m))
    ref = PchipInterpolator(g, v)  # SciPy's monotone cubic, plateaus and all
    s_lo, s_hi = (float(x) for x in thrusters.map_range(P, m))
    x = np.linspace(s_lo, s_hi, 2001)
    F = np.array(ca.evalf(thrusters.map_thrust(P, m, ca.DM(x)))).ravel()
    np.testing.assert_allclose(F, ref(x), rtol=1e-12, atol=1e-12)
    assert np.all(np.diff(F) >= -1e-12)  # monotone to round-off
    np.testing.assert_allclose(F[x >= g[-5]], v[-1], rtol=0, atol=1e-12)  # flat on the forward plateau
    np.testing.assert_allclose(F[x <= g[3]], v[0], rtol=0, atol=1e-12)  # and on the reverse one
    u = np.linspace(-30.4, 30.4, 41)  # the allocation's range inverts through the strictly increasing part
    y = np.array(ca.evalf(thrusters.map_inverse(P, m, ca.DM(u)))).ravel()
    np.testing.assert_allclose(np.array(ca.evalf(thrusters.map_thrust(P, m, ca.DM(y)))).ravel(), u, atol=1e-9)
    from arvcas.model import thruster_tables as tt  # the closed loop's own inverse (interval lookup in MX, then Newton)

    gx, vx, dx = (ca.MX(ca.DM(np.array(ca.evalf(a)).ravel())) for a in thrusters.map_table(P, m))
    uu = ca.MX.sym("u", u.size)
    inv = ca.Function("inv", [uu], [tt.pchip_newton(*tt.pchip_interval(gx, vx, dx, uu), uu)])
    np.testing.assert_allclose(np.array(inv(u)).ravel(), y, atol=1e-9)


@pytest.mark.parametrize("kw, match", [
    (dict(u_max="51.43622732069733"), r"thrusters\.T1\.u_max: 51\.4362 N lies on the saturation plateau of its map "
                                      r"t200_16v \(51\.4362 N from command 1900 us on\)"),
    (dict(middle=True), r"thrust .* at points \d+ and \d+: flat only at zero thrust \(the dead band\) and at the "
                        r"table's ends"),
])
def test_plateau_refusals(tmp_path, kw, match):
    with pytest.raises(ParamsError, match=match) as e:
        load(_plateau_system(tmp_path, **kw))
    assert "\n" not in str(e.value)


# ---- a scenario without [arm] ------------------------------------------------------------------------------


def test_scenario_without_arm():
    cfg = scenario.load_scenario(arvcas.load_system("bluerov2").params.default("scenario"))
    assert not profiles.has_arm_motion(cfg)
    assert not re.search(r"^\[(arm|payload)", cfg.text, re.M)
    assert scenario.loads_scenario(cfg.to_toml()).to_toml() == cfg.to_toml()
    # a system with an arm under a scenario without one holds its stow pose, carries nothing
    heavy = arvcas.load_system("bluerov2_heavy_alpha5")
    q0 = ca.DM([heavy.params[f"arm.stow.q{i}"] for i in range(1, 5)])
    limits.check_joint_limits(cfg, heavy.params)
    for t in (0.0, 7.5, 60.0):
        q, qd, qdd = profiles.joint_trajectory(cfg, q0, t)
        np.testing.assert_array_equal(np.array(q), np.array(q0))
        assert float(ca.norm_inf(qd)) == float(ca.norm_inf(qdd)) == 0.0
        assert float(profiles.payload_profile(cfg, t)) == 0.0


def test_task_without_arm():
    """A vehicle task (docs/tasks.md) in a scenario without [arm]: loaded, and checked against the thrusters
    of the six-thruster BlueROV2 (its allocation without pitch) before any compile."""
    s = arvcas.load_system("bluerov2")
    base = s.params.default("scenario").read_text()
    approach = ('\n[trajectory]\npattern = "approach"\n'
                'target = { value = [0.5, 0.2, 0.1, 0, 0, 0.3], unit = "m,m,m,rad,rad,rad", source = "test" }\n'
                'start = { value = 2.0, unit = "s", source = "test" }\n'
                'duration = { value = 20.0, unit = "s", source = "test" }\n')
    cfg = scenario.loads_scenario(base + approach, "task.toml")
    assert cfg.trajectory_pattern == "approach" and not profiles.has_arm_motion(cfg)
    limits.check_trajectory_limits(cfg, s.params)
    fast = scenario.loads_scenario(base + approach.replace("value = 20.0", "value = 0.5"), "task.toml")
    with pytest.raises(scenario.ScenarioError, match=r"thruster T\d .* of its limit"):
        limits.check_trajectory_limits(fast, s.params)


def test_scenario_payload_without_arm_motion_refused():
    text = arvcas.load_system("bluerov2").params.default("scenario").read_text()
    text += '\n[[payload.event]]\nt = { value = 1.0, unit = "s", source = "x" }\nramp = { value = 0.5, unit = "s", ' \
            'source = "x" }\nto = { value = 1.0, unit = "1", source = "x" }\n'
    with pytest.raises(scenario.ScenarioError, match=r"payload\.event: a payload is carried by the arm"):
        scenario.loads_scenario(text, "s.toml")


# ---- every mismatch between a system and a log, before any compile --------------------------------------


def _log(tmp_path, name: str, joints: bool = False, thrust: str | None = None) -> str:
    t = np.arange(101) / 50.0
    z = np.zeros_like(t)
    np.savetxt(tmp_path / f"{name}.csv", np.column_stack([t, z, z, z + 1.0, z, z, z, z + 1.0, z, z, z, z]),
               delimiter=",", header="t,x,y,z,qx,qy,qz,qw,wx,wy,wz,f", comments="", fmt="%.10g")
    extra = ""
    if joints:
        extra += '[stream.joints]\nq1 = { column = "wx" }\n'
    if thrust:
        extra += f'[stream.thrust]\n{thrust} = {{ columns = ["f"], unit = "N" }}\n'
    text = f"""[log]
name = "{name}"
rate = 50.0
passive = {str(thrust is None).lower()}

[[stream]]
file = "{name}.csv"
time = "t"
position = {{ columns = ["x", "y", "z"], unit = "m" }}
quaternion = {{ columns = ["qx", "qy", "qz", "qw"] }}
angular_velocity = {{ columns = ["wx", "wy", "wz"], unit = "rad/s" }}
{extra}"""
    path = tmp_path / f"{name}.log.toml"
    path.write_text(text)
    return str(path)


@pytest.fixture
def no_compile(monkeypatch):
    """Every compile of the log plant raises: a refusal that passes came before any."""
    def boom(*a, **k):
        raise AssertionError("compiled before refusing")

    for f in ("step_fn", "block_fn", "sens_fn"):
        monkeypatch.setattr(plant.LogPlant, f, boom)
    from arvcas.build import codegen

    for f in [f for f in dir(codegen) if f.startswith(("compile", "build"))]:
        monkeypatch.setattr(codegen, f, boom)


@pytest.mark.parametrize("system, log_kw, cli_match, match", [
    ("bluerov2_heavy_alpha5", {}, None,
     r"bluerov2_heavy_alpha5 has an arm of 4 joints but the log maps none: map q1, q2, q3, q4"),
    ("bluerov2", dict(joints=True), r"stream\[1\]\.joints\.q1: the system has no arm: remove the joints",
     r"joints\.q1: bluerov2 has no arm, but the log maps joints q1"),
    ("bluerov2_heavy_alpha5", dict(joints=True), r"joints q2, q3, q4 are not mapped \(map every joint or none\)",
     r"joints\.q2: bluerov2_heavy_alpha5 has joints q1, q2, q3, q4, the log maps q1"),
])
def test_log_mismatch_refused_before_compile(tmp_path, capsys, no_compile, system, log_kw, cli_match, match):
    """The command line reads the log against the system (its own one-line refusals) and checks what is left;
    the API (a log read alone) refuses the same mismatch by :func:`arvcas.ident.plant.check_log`."""
    path = _log(tmp_path, "a1", **log_kw)
    out = tmp_path / "out"
    rc = cli.main(["validate", "--system", system, path, "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and re.search(cli_match or match, err[0]), err
    assert not out.exists()
    s = arvcas.load_system(system)
    lg = logs.load_log(path)  # unchecked against the system: the API refuses it too
    with pytest.raises(logs.LogError, match=match):
        validate.validate_log(s, lg)
    from arvcas.ident.identify import identify

    with pytest.raises(logs.LogError, match=match):
        identify(s, [lg], ["vehicle.zB"])


def test_log_thruster_mismatch_refused_before_compile(tmp_path, capsys, no_compile):
    rc = cli.main(["validate", "--system", "bluerov2", _log(tmp_path, "a2", thrust="T7"), "--out",
                   str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "thrust.T7: the system has no thruster 'T7'" in err[0], err
    lg = logs.load_log(_log(tmp_path, "a3", thrust="T7"))
    with pytest.raises(logs.LogError, match=r"thrust\.T7: bluerov2 has no thruster 'T7' \(it has T1, T2, T3, T4, T5, T6\)"):
        validate.validate_log(arvcas.load_system("bluerov2"), lg)


# ---- station keeping of the armless systems, end to end ---------------------------------------------------


@pytest.mark.parametrize("name", ["bluerov2", "bluerov2_heavy"])
def test_station_keeping_cli_and_api(name, tmp_path, capsys, cache):
    """The system's own defaults (scenario without [arm], gains) through ``arvcas simulate`` and through the
    API give the same run; it holds station; the thrust the allocation asks is the minimum-norm solution of
    the actuated rows (NumPy's pseudo-inverse) wherever no thruster saturates."""
    from arvcas.io import results
    from arvcas.sim.simulation import simulate

    s = arvcas.load_system(name)
    text = s.params.default("scenario").read_text().replace("duration = { value = 60.0", "duration = { value = 4.0")
    cfg_path = tmp_path / "short.toml"
    cfg_path.write_text(text)
    out = tmp_path / "run.h5"
    rc = cli.main(["simulate", "--system", name, "--controller", "pid", "--config", str(cfg_path), "--out", str(out)])
    printed = capsys.readouterr().out
    assert rc == 0 and "DIVERGED" not in printed and "theta" in printed
    r = results.read_result(out)
    ref = simulate("pid", seed=0, system=s.params, cfg=scenario.load_scenario(cfg_path))
    np.testing.assert_array_equal(r.eta, ref.eta)
    assert ref.ok and np.all(np.abs(ref.e[:, :3]) < 0.1) and np.all(np.abs(ref.e[:, 3:]) < 0.3)
    B = _B(s)
    rows = [k for k in range(6) if k not in s.structure.unactuated]
    u, tau = ref.thrust_cmd, ref.tau_cmd
    free = np.all(np.abs(u) < 30.4 - 1e-9, axis=1)
    assert free.sum() > 0.8 * len(free)
    np.testing.assert_allclose(u[free], tau[free][:, rows] @ np.linalg.pinv(B[rows]).T, atol=1e-9)


def test_armless_log_validated_and_identified_end_to_end(tmp_path, capsys, cache):
    """A passive trial of the BlueROV2 Heavy (synthetic: released tilted, it rocks back; mocap and gyro
    noise, no joints stream) is validated against the system that made it (errors at the noise level) and
    identifies its centre of buoyancy from a start 3 times off: through the command line, no arm anywhere."""
    import json

    import tomlkit

    from arvcas.ident import synthetic

    s = arvcas.load_system("bluerov2_heavy")
    trial = synthetic.write_trial(tmp_path / "logs", "rock", s, duration=8.0, seed=2)
    assert "joints" not in trial.read_text()
    out = tmp_path / "val"
    assert cli.main(["validate", "--system", "bluerov2_heavy", str(trial), "--out", str(out), "--figures", "--format", "svg"]) == 0
    assert json.loads((out / "validation.json").read_text())["system"] == "bluerov2_heavy"
    rmse = validate.validate_log(s, logs.load_log(trial)).metrics["rmse"]
    assert rmse["roll"] < 3 * synthetic.NOISE["attitude"] and rmse["pitch"] < 3 * synthetic.NOISE["attitude"], rmse
    doc = tomlkit.parse(open(s.path, encoding="utf-8").read())
    doc["vehicle"]["zB"]["value"] = -0.03  # the start: 3 times the truth's -0.01 m
    doc.pop("defaults")
    start = tmp_path / "bluerov2_heavy_start.toml"
    start.write_text(tomlkit.dumps(doc))
    ident = tmp_path / "bluerov2_heavy_identified.toml"
    capsys.readouterr()
    assert cli.main(["identify", "--system", str(start), "--free", "vehicle.zB", str(trial), "--out", str(ident),
                     "--max-iter", "30"]) == 0
    zb = arvcas.load_system(ident).params["vehicle.zB"]  # the identified file loads
    assert zb == pytest.approx(-0.01, rel=0.05), zb
