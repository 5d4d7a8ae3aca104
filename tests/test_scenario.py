"""Scenario data (docs/model.md §4): strict loading, the effective-config round trip, trajectory, disturbance, noise."""

from __future__ import annotations

import dataclasses
import math

import casadi as ca
import numpy as np
import pytest

from arvcas.sim import limits, profiles, scenario
from arvcas.system.params import load as load_params
from arvcas.sim.scenario import ScenarioError, default_scenario_path, load_scenario, loads_scenario

TEXT = default_scenario_path().read_text()


@pytest.fixture(scope="module")
def cfg():
    return load_scenario()


def _write(tmp_path, text, name="s.toml", binary=False):
    p = tmp_path / name
    if binary:
        p.write_bytes(text)
    else:
        p.write_text(text)
    return p


# (old, new, fragment): the packaged file with its one occurrence of ``old`` replaced by ``new`` is refused
# with a one-line ScenarioError that starts with the path and contains ``fragment``
BAD_EDITS = [
    ("[time]", "[time", "malformed TOML"),
    ("duration =", "durration =", "unknown key 'time.durration' (did you mean 'time.duration'?)"),
    ('h_plant = { value = 0.05, unit = "s", source = "results/step/README.md: the coarsest step dividing h within 1e-6 m, rad of CVODES and 1e-5 relative in CHAT/RMSE of the 0.01 s run (docs/model.md §4); every other step stays available here" }' + "\n", "", "missing key 'time.h_plant'"),
    ("duration = { value = 100.0,", 'duration = { value = "long",', "time.duration: value must be a number"),
    ("duration = { value = 100.0,", "duration = { value = nan,", "time.duration: value must be finite"),
    ("duration = { value = 100.0,", "duration = { value = inf,", "time.duration: value must be finite"),
    ("duration = { value = 100.0,", "duration = { value = -1.0,", "time.duration: value must be > 0"),
    ("h = { value = 0.1,", "h = { value = 0.015,", "must be a whole multiple of time.h_plant"),
    ("q_nu = { value = 1e-7,", "q_nu = { value = 0.0,", "ekf.q_nu: value must be > 0"),
    ("qg = { value = [60.0, 60.0, -60.0, 0.0, 60.0, 0.0],", "qg = { value = [60.0, 60.0],", "arm.qg: value must be a list of 6 numbers"),
    ("reach_end = { value = 20.0,", "reach_end = { value = 30.0,", "arm times must satisfy"),
    ('duration = { value = 100.0, unit = "s", source', 'duration = { value = 100.0, unit = "s", sauce', "expected a table { value, unit, source }"),
    # units, element by element
    # an example: "degrees" used to be read silently as radians
    ('0.0, 60.0, 0.0], unit = "deg"', '0.0, 60.0, 0.0], unit = "degrees"',
     "arm.qg: unknown unit 'degrees' (allowed for an angle: rad, deg)"),
    ('unit = "m,m,m,deg,deg,deg"', 'unit = "m,m,m,degrees,deg,deg"', "initial.eta0: unknown unit 'degrees' of element 4"),
    ('unit = "m,m,m,deg,deg,deg"', 'unit = "deg,m,m,deg,deg,deg"',
     "initial.eta0: unit 'deg' of element 1 is not a length (allowed: m, mm, cm)"),
    ('unit = "m,m,m,deg,deg,deg"', 'unit = "deg"', "initial.eta0: one unit 'deg' for elements of length and angle"),
    ('unit = "m/s,rad/s"', 'unit = "rad/s,m/s"', "initial.nu0: unit 'rad/s' of element 1 is not a velocity"),
    ('unit = "m/s,rad/s"', 'unit = "m/s,rad/s,m/s"', "initial.nu0: unit list 'm/s,rad/s,m/s' does not match 6 values"),
    ('unit = "N,N,N,N*m,N*m,N*m", source = "eq. 41" }\namplitude', 'unit = "N,N,N,N,N*m,N*m", source = "eq. 41" }\namplitude',
     "disturbance.offset: unit 'N' of element 4 is not a torque (allowed: N*m)"),
    ('duration = { value = 100.0, unit = "s"', 'duration = { value = 100.0, unit = "min"',
     "time.duration: unknown unit 'min' (allowed for a time: s, ms)"),
    ('unit = "m or rad"', 'unit = "m or deg"', "atd.A_min: unit 'm or deg': one number for length and angle needs units of one scale"),
    ('unit = "m or rad"', 'unit = "m"', "atd.A_min: unit 'm' is not a length or angle (allowed: m or rad)"),
    ('unit = "rad", source = "arvcas choice" }', 'unit = "m", source = "arvcas choice" }',
     "limits.e_attitude: unit 'm' is not an angle (allowed: rad, deg)"),
    ('var_position = { value = 1e-4, unit = "m^2"', 'var_position = { value = 1e-4, unit = "m"',
     "sensors.var_position: unit 'm' is not a length^2 (allowed: m^2)"),
]


@pytest.mark.parametrize("old,new,fragment", BAD_EDITS, ids=[f[2].split(":")[0] + ":" + f[1][:24] for f in BAD_EDITS])
def test_bad_scenario_files_one_line(tmp_path, old, new, fragment):
    assert TEXT.count(old) == 1, old
    p = _write(tmp_path, TEXT.replace(old, new))
    with pytest.raises(ScenarioError) as ei:
        load_scenario(p)
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith(f"{p}: ") and fragment in msg, msg


def test_unreadable_inputs(tmp_path):
    with pytest.raises(ScenarioError, match="file not found"):
        load_scenario(tmp_path / "nope.toml")
    with pytest.raises(ScenarioError, match="is a directory"):
        load_scenario(tmp_path)
    p = _write(tmp_path, b"[time]\nduration = \xff\xfe\n", binary=True)
    with pytest.raises(ScenarioError, match="not UTF-8"):
        load_scenario(p)


def test_values_in_si(cfg):
    assert cfg.initial_eta0[3] == pytest.approx(math.pi / 90)  # eta0 attitude: pi/90 (section 4.2)
    assert cfg.arm_qg[4] == pytest.approx(math.radians(60))
    assert cfg.substeps == 2 and scenario.n_samples(cfg) == 1001  # h_plant = 0.05 s (results/step)
    np.testing.assert_allclose(cfg.sensor_variances[[0, 3, 6]], [1e-4, 2.74e-5, 2.5e-7])


def test_effective_config_round_trip(cfg):
    c2 = dataclasses.replace(cfg, time_duration=7.0, ekf_q_nu=3e-8).with_h(0.05)
    back = loads_scenario(c2.to_toml())
    for f in dataclasses.fields(c2):
        if f.name not in ("text", "path"):
            assert getattr(back, f.name) == getattr(c2, f.name), f.name


def test_quintic_trajectory(cfg):
    """Rest-to-rest quintics (zero end velocity and acceleration) hold q0, reach qg at 20 s, return by 40 s."""
    P = load_params()
    q0 = ca.DM([P[f"arm.stow.q{i}"] for i in range(1, 7)])
    t = ca.SX.sym("t")
    f = ca.Function("traj", [t], list(profiles.joint_trajectory(cfg, q0, t)))
    for tt, q_expect in ((0.0, q0), (5.0, q0), (20.0, ca.DM(cfg.arm_qg)), (24.0, ca.DM(cfg.arm_qg)), (40.0, q0), (90.0, q0)):
        q, qd, qdd = (np.array(v).ravel() for v in f(tt))
        np.testing.assert_allclose(q, np.array(q_expect).ravel(), atol=1e-12)
        np.testing.assert_allclose(qd, 0, atol=1e-12)
    # derivatives are consistent with the position (central differences)
    for tt in (7.3, 12.5, 31.0):
        e = 1e-5
        qp, qm = np.array(f(tt + e)[0]).ravel(), np.array(f(tt - e)[0]).ravel()
        np.testing.assert_allclose((qp - qm) / (2 * e), np.array(f(tt)[1]).ravel(), atol=1e-8)
        dp, dm = np.array(f(tt + e)[1]).ravel(), np.array(f(tt - e)[1]).ravel()
        np.testing.assert_allclose((dp - dm) / (2 * e), np.array(f(tt)[2]).ravel(), atol=1e-7)
    limits.check_joint_limits(cfg, P)


def test_payload_ramp_and_disturbance(cfg):
    t = ca.SX.sym("t")
    pl = ca.Function("pl", [t], [profiles.payload_profile(cfg, t)])
    assert float(pl(21.9)) == 0 and float(pl(22.25)) == pytest.approx(0.5) and float(pl(23)) == 1
    d = ca.Function("d", [t], [profiles.disturbance(cfg, t, ca.DM(cfg.disturbance_phase))])
    for tt in (0.0, 13.7, 55.0):
        expect = [5 + 3 * math.sin(0.2 * tt + math.pi / 5), 5 + 4 * math.cos(0.3 * tt + math.pi / 6),
                  10 + 8 * math.cos(0.2 * tt), 25 + 16 * math.sin(0.2 * tt),
                  30 + 15 * math.sin(0.2 * tt + math.pi / 4), 8 + 6 * math.cos(0.3 * tt)]
        np.testing.assert_allclose(np.array(d(tt)).ravel(), expect, rtol=1e-12, atol=1e-12)  # eq. 41


def test_noise_sequence_seeded(cfg):
    a, b, c = (profiles.noise_sequence(cfg, s) for s in (3, 3, 4))
    assert a.shape == (12, 1001)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    np.testing.assert_allclose(a.var(axis=1), cfg.sensor_variances, rtol=0.15)
    with pytest.raises(ScenarioError, match="seed"):
        profiles.noise_sequence(cfg, -1)


def test_joint_limit_check_names_the_joint(cfg):
    P = load_params().replace({"arm.stow.q3": math.radians(45)})
    with pytest.raises(ScenarioError, match="arm.stow \\(q0\\): joint 3 target 45.00 deg outside Table 1 limits \\[-90, 30\\] deg"):
        limits.check_joint_limits(cfg, P)
