"""A scenario's sensor set (docs/sensors.md): a BlueROV2 Heavy + Alpha 5 with only an IMU and a depth sensor.

- the scenario: what is measured and held, the default (no sensor set: the whole [eta; nu] at every
  sample, today's runs), refusals of a set that cannot observe what the task holds, in one line before
  any compile;
- a station-keeping run: its EKF estimate against an independent NumPy EKF (a batch update on the measured
  components, the Jacobian by complex-step differentiation) fed the run's own measurements, the depth sensor at half
  the controller's rate; RMSE and divergence on the held DOFs only, the horizontal drift reported;
- the exported controller takes exactly those 7 measurements and, closed around the plant, reproduces the
  compiled run (as tests/test_export_controller.py does for the full state);
- a short tuning study with the same sensors runs to its end, its objectives on the held DOFs.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import replace

import numpy as np
import pytest

import arvcas
from arvcas import cli
from arvcas.export.closeloop import close_loop, load_binding
from arvcas.export.controller import default_prefix
from arvcas.sim import profiles, scenario
from arvcas.sim.scenario import ScenarioError, loads_scenario
from arvcas.system import load_system
from arvcas.tuning import checkpoint as ck
from arvcas.tuning.front import read_front

from make_helpers import make_cmd
from studytext import tiny_study

SYSTEM = "bluerov2_heavy_alpha5"
SEED = 4
IMU_DEPTH = {"sensors_imu_period": 0.1, "sensors_depth_period": 0.2}  # the depth every second sample


def _base():
    s = load_system(SYSTEM)
    return s, scenario.load_scenario(s.params.default("scenario"))


def _cfg():
    """The BlueROV2's scenario cut to 20 s, without its current and with plain RK4 (as the exported plant of
    close_loop needs: tests/test_export_controller.py), with only an IMU and a depth sensor."""
    s, cfg = _base()
    return s, replace(cfg, time_duration=20.0, current_velocity=None, time_thrust_quadrature=None, **IMU_DEPTH)


# ---- the scenario ------------------------------------------------------------------------------------------


def test_no_sensor_set_is_the_whole_state():
    _, cfg = _base()
    assert scenario.sensor_set(cfg) is None and scenario.held_dofs(cfg) == (True,) * 6
    assert scenario.measured(cfg) == tuple((i, "state", 1) for i in range(12))


def test_imu_and_depth_hold_depth_attitude_heading():
    _, cfg = _cfg()
    assert scenario.sensor_set(cfg) == (("imu", 1), ("depth", 2))
    assert [scenario.COMPONENTS[i] for i, _, _ in scenario.measured(cfg)] == ["z", "phi", "theta", "psi", "p", "q", "r"]
    assert scenario.held_dofs(cfg) == (False, False, True, True, True, True)
    back = loads_scenario(cfg.to_toml(), "round trip")  # result files store the effective scenario
    assert scenario.sensor_set(back) == scenario.sensor_set(cfg)
    full = replace(cfg, sensors_dvl_period=0.1, sensors_position_period=1.0)
    assert scenario.held_dofs(full) == (True,) * 6 and len(scenario.measured(full)) == 12
    assert dict(scenario.sensor_set(full))["position"] == 10


def _text(extra: str, base: str | None = None) -> str:
    _, cfg = _base()
    return (base or cfg.text).replace("\n[ekf]", "\n" + extra + "\n[ekf]")


@pytest.mark.parametrize("extra,fragment", [
    ('dvl_period = { value = 0.1, unit = "s", source = "t" }', "sensors.imu_period: missing: a sensor set needs the imu"),
    ('imu_period = { value = 0.02, unit = "s", source = "t" }', "sensors.depth_period: missing: a sensor set needs the depth"),
    ('imu_period = { value = 0.1, unit = "s", source = "t" }\ndepth_period = { value = 0.15, unit = "s", source = "t" }',
     "sensors.depth_period: 0.15 s must be at most time.h (0.1 s) or a whole multiple of it"),
    ('imu_period = { value = 0.1, unit = "s", source = "t" }\ndepth_period = { value = -1, unit = "s", source = "t" }',
     "sensors.depth_period"),
])
def test_a_set_that_cannot_hold_the_task_is_refused_in_one_line(extra, fragment):
    with pytest.raises(ScenarioError) as ei:
        loads_scenario(_text(extra), "s.toml")
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith("s.toml: ") and fragment in msg, msg


@pytest.mark.parametrize("extra,fragment", [
    ('imu_period = { value = 0.1, unit = "s", source = "t" }\ndepth_period = { value = 0.1, unit = "s", source = "t" }\n'
     'depth_latency = { value = 0.15, unit = "s", source = "t" }',
     "sensors.depth_latency: 0.15 s must be a whole multiple of time.h (0.1 s), from 0 to 10 samples (1 s)"),
    ('imu_period = { value = 0.1, unit = "s", source = "t" }\ndepth_period = { value = 0.1, unit = "s", source = "t" }\n'
     'imu_latency = { value = 1.1, unit = "s", source = "t" }',
     "sensors.imu_latency: 1.1 s must be a whole multiple of time.h (0.1 s), from 0 to 10 samples (1 s)"),
    ('imu_period = { value = 0.1, unit = "s", source = "t" }\ndepth_period = { value = 0.1, unit = "s", source = "t" }\n'
     'dvl_latency = { value = 0.1, unit = "s", source = "t" }',
     "sensors.dvl_latency: the dvl sensor is not fitted (no sensors.dvl_period)"),
    ('position_latency = { value = 0.1, unit = "s", source = "t" }',
     "sensors.position_latency: the position sensor is not fitted (no sensors.position_period)"),
    ('imu_period = { value = 0.1, unit = "s", source = "t" }\ndepth_period = { value = 0.1, unit = "s", source = "t" }\n'
     'depth_latency = { value = -0.1, unit = "s", source = "t" }', "sensors.depth_latency"),
])
def test_a_latency_that_is_not_whole_samples_is_refused_in_one_line(extra, fragment):
    with pytest.raises(ScenarioError) as ei:
        loads_scenario(_text(extra), "s.toml")
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith("s.toml: ") and fragment in msg, msg


def test_latencies_in_samples_and_round_trip():
    _, cfg = _cfg()
    lagged = replace(cfg, sensors_depth_latency=0.3, sensors_imu_latency=0.0)
    assert scenario.latencies(lagged) == (("depth", 3),)  # 0: not lagging
    back = loads_scenario(lagged.to_toml(), "round trip")
    assert back.sensors_depth_latency == 0.3 and scenario.latencies(back) == (("depth", 3),)
    assert scenario.latencies(cfg) == () and lagged.graph_key() != cfg.graph_key()
    assert replace(cfg, sensors_depth_latency=0.0).graph_key() == cfg.graph_key()  # 0 is none
    assert scenario.latencies(lagged.with_h(0.05)) == (("depth", 6),)  # the same time, in the new samples
    with pytest.raises(ScenarioError, match=r"^ScenarioConfig.with_h: sensors.depth_latency: 0.3 s must be a whole "
                                            r"multiple of time.h \(0.2 s\)"):
        lagged.with_h(0.2)


def test_a_trajectory_without_a_position_fix_is_refused_before_compile(tmp_path, capsys):
    from pathlib import Path

    track = (Path(__file__).resolve().parents[1] / "studies/scenarios/bluerov2_tracking.toml").read_text()
    bad = tmp_path / "track.toml"
    bad.write_text(_text('imu_period = { value = 0.1, unit = "s", source = "t" }\n'
                         'depth_period = { value = 0.1, unit = "s", source = "t" }', track))
    assert cli.main(["simulate", "--system", SYSTEM, "--controller", "pid", "--config", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "sensors.position_period: missing: a trajectory task moves the vehicle in x, y" in err
    assert "compiling" not in err


# ---- a run, its export and a study with only IMU and depth --------------------------------------------------


def _J(eta):
    ph, th, ps = eta[3:6]
    c, s = np.cos, np.sin
    R = np.array([[c(ps) * c(th), -s(ps) * c(ph) + c(ps) * s(th) * s(ph), s(ps) * s(ph) + c(ps) * c(ph) * s(th)],
                  [s(ps) * c(th), c(ps) * c(ph) + s(ph) * s(th) * s(ps), -c(ps) * s(ph) + s(th) * s(ps) * c(ph)],
                  [-s(th), c(th) * s(ph), c(th) * c(ph)]])
    T = np.array([[1, s(ph) * np.tan(th), c(ph) * np.tan(th)], [0, c(ph), -s(ph)], [0, s(ph) / c(th), c(ph) / c(th)]])
    J = np.zeros((6, 6), dtype=np.result_type(eta, float))  # complex under the complex step
    J[0:3, 0:3], J[3:6, 3:6] = R, T
    return J


def numpy_ekf(cfg, y, sset):
    """An independent EKF (docs/model.md "EKF", docs/sensors.md): constant-velocity transition, its Jacobian by
    complex-step differentiation (exact to round-off), a batch update K = P H' (H P H' + R)^-1 on the components
    measured and due at sample k; ``sset``: {component index: every}. Returns eta_hat (N + 1, 6)."""
    h, r = cfg.time_h, cfg.sensor_variances
    Q = np.diag([cfg.ekf_q_eta] * 6 + [cfg.ekf_q_nu] * 6)
    f = lambda x: np.concatenate([x[0:6] + h * _J(x[0:6]) @ x[6:12], x[6:12]])  # noqa: E731
    out = []
    for k in range(y.shape[1]):
        if k == 0:
            x = np.array([y[i, 0] if i in sset else 0.0 for i in range(12)])
            P = np.diag(r)
        S = [i for i in sorted(sset) if k % sset[i] == 0]
        H = np.eye(12)[S]
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + np.diag(r[S]))
        x = x + K @ (y[S, k] - x[S])
        P = (np.eye(12) - K @ H) @ P
        out.append(x[0:6].copy())
        F = np.column_stack([f(x + 1e-30j * d).imag / 1e-30 for d in np.eye(12)])
        x, P = f(x), F @ P @ F.T + Q
    return np.array(out)


@pytest.fixture(scope="module")
def imu_depth_run():
    s, cfg = _cfg()
    run = arvcas.Run("pid", scenario=cfg, system=s.params).compile()
    return s, cfg, run, run.simulate(seed=SEED)


def test_station_keeping_with_imu_and_depth(imu_depth_run):
    """The run holds depth, attitude and heading; its EKF is the NumPy EKF on the 7 measured components, the
    depth read every second sample (to 1e-12; the same EKF reading the depth at every sample is 3 cm off in z)."""
    s, cfg, run, r = imu_depth_run
    assert r.ok
    assert np.all(r.rmse[0:2] == 0) and np.all(r.rmse[2:6] > 0)  # x, y are not held: no error counted
    y = np.hstack([r.eta, r.nu]).T + profiles.noise_sequence(cfg, SEED)
    sset = {i: every for i, _, every in scenario.measured(cfg)}
    ref = numpy_ekf(cfg, y, sset)
    worst = np.abs(ref - r.eta_hat).max()
    assert worst < 1e-12, worst  # measured 1.2e-14 m
    every_sample = numpy_ekf(cfg, y, {i: 1 for i in sset})
    assert np.abs(every_sample - r.eta_hat)[:, 2].max() > 1e-3  # the depth's rate is what the run did (3 cm)


LAGGED = {"sensors_imu_latency": 0.1, "sensors_depth_latency": 0.3}  # 1 and 3 samples; depth every 2 samples


@pytest.fixture(scope="module")
def lagged_run():
    s, cfg = _cfg()
    cfg = replace(cfg, **LAGGED)
    run = arvcas.Run("pid", scenario=cfg, system=s.params).compile()
    return s, cfg, run, run.simulate(seed=SEED)


def _lagged(x, d):
    """x (12, N + 1) with component i taken from sample k - d[i] (before sample 0: the state of sample 0)."""
    return np.array([[x[i, max(k - d[i], 0)] for k in range(x.shape[1])] for i in range(12)])


def test_lagging_sensors_fused_as_they_arrive(imu_depth_run, lagged_run):
    """The reading that arrives at sample k is the state of sample k - d plus sample k's noise; the EKF fuses it as
    the state of sample k: it is the NumPy EKF fed those readings (to 1e-12). Fed the readings without their lag
    it is far off (the delay is in the run)."""
    s, cfg, run, r = lagged_run
    assert r.ok
    x, noise = np.hstack([r.eta, r.nu]).T, profiles.noise_sequence(cfg, SEED)
    d = [0] * 12
    for i in scenario.SENSORS["imu"]:
        d[i] = 1
    d[2] = 3
    sset = {i: every for i, _, every in scenario.measured(cfg)}
    ref = numpy_ekf(cfg, _lagged(x, d) + noise, sset)
    worst = np.abs(ref - r.eta_hat).max()
    assert worst < 1e-12, worst
    fresh = numpy_ekf(cfg, x + noise, sset)
    assert np.abs(fresh - r.eta_hat)[:, 2].max() > 1e-3
    r0 = imu_depth_run[3]
    assert not np.array_equal(r0.eta, r.eta)  # the lag changed what the controller did


def test_lagging_sensors_in_lockstep_lanes(lagged_run):
    """The shift register is loop state like any other: W runs in lockstep give the scalar runs' bits."""
    s, cfg, run, r = lagged_run
    G = np.asarray(run.default_gains())[None, :] * np.array([[1.0], [0.8], [1.2], [0.9], [1.1]])
    seeds = np.arange(5) + SEED
    ref = run.many(G, seeds, n_threads=1, lockstep=False)
    got = run.many(G, seeds, n_threads=2, lockstep=True)
    for a, b, name in zip(ref, got, ("chat", "rmse", "ok", "t_fail")):
        assert a.tobytes() == b.tobytes(), name
    np.testing.assert_array_equal(ref[1][0], r.rmse)  # row 0: the default gains, seed SEED: the traced run's


def test_latency_zero_is_the_run_without_latency(imu_depth_run):
    """Latency 0 given for every fitted sensor: the same compiled arithmetic (run digest) and the same run, bit
    for bit."""
    s, cfg, run, r = imu_depth_run
    zero = replace(cfg, sensors_imu_latency=0.0, sensors_depth_latency=0.0)
    run0 = arvcas.Run("pid", scenario=zero, system=s.params).compile()
    assert run0.digest() == run.digest()
    r0 = run0.simulate(seed=SEED)
    for k in ("eta", "nu", "eta_hat", "tau_cmd"):
        np.testing.assert_array_equal(r0.series[k], r.series[k], err_msg=k)
    np.testing.assert_array_equal(r0.rmse, r.rmse)
    np.testing.assert_array_equal(r0.chat, r.chat)


def test_simulate_reports_held_dofs_and_drift(tmp_path, capsys):
    s, cfg = _cfg()
    p = tmp_path / "imu_depth.toml"
    p.write_text(cfg.to_toml(), encoding="utf-8")
    assert cli.main(["simulate", "--system", SYSTEM, "--controller", "pid", "--config", str(p),
                     "--seed", str(SEED)]) == 0
    out = capsys.readouterr().out
    assert "not held" in out and "held: z, phi, theta, psi (no position sensor); RMSE on those only." in out
    assert "horizontal drift (not held):" in out


def _export(cfg, d):
    """``arvcas export-controller`` of pid for ``cfg``, built: (its directory, the binding's module, a controller)."""
    if shutil.which("make") is None or shutil.which("c++") is None:
        pytest.skip("make or c++ is not installed")
    (d / "scenario.toml").write_text(cfg.to_toml(), encoding="utf-8")
    assert cli.main(["export-controller", str(d / "out"), "--controller", "pid", "--system", SYSTEM,
                     "--config", str(d / "scenario.toml")]) == 0
    subprocess.run(make_cmd(d / "out"), check=True, capture_output=True, timeout=600)
    mod, ctl = load_binding(d / "out")
    return d / "out", mod, ctl


@pytest.fixture(scope="module")
def exported(imu_depth_run, tmp_path_factory):
    return _export(imu_depth_run[1], tmp_path_factory.mktemp("ctl_imu_depth"))


def _reproduces(ctl, run, r):
    """Closed around the plant the exported controller reproduces the compiled run (1e-12); fed the run's own
    states it returns the run's estimate and commands bit for bit."""
    ctl.reset()
    e = close_loop(ctl, run, seed=SEED)
    for k in ("eta", "nu", "eta_hat", "tau_cmd"):
        a, b = e[k].reshape(r.series[k].shape), r.series[k]
        assert np.abs(a - b).max() <= 1e-12 * max(1.0, np.abs(b).max()), k
    np.testing.assert_allclose(e["rmse"], r.rmse, rtol=1e-12, atol=0)
    dyn = run.params.structure.has_thruster_dynamics
    e = close_loop(ctl, run, seed=SEED, states=np.hstack([r.eta, r.nu]), delivered=r.thrust if dyn else None)
    for k in ("eta_hat", "eta_ref", "tau_cmd"):
        np.testing.assert_array_equal(e[k].reshape(r.series[k].shape), r.series[k], err_msg=k)


def test_exported_controller_takes_only_imu_and_depth(imu_depth_run, exported):
    """Its measurement vector is the 7 measured components, documented in the header with each sensor's rate;
    closed around the plant it reproduces the compiled run (1e-12), and fed the run's own measurements it
    returns the run's estimate and commands bit for bit."""
    s, cfg, run, r = imu_depth_run
    out, mod, ctl = exported
    assert mod.N_Y == 7 and mod.MEASURED == ["z", "phi", "theta", "psi", "p", "q", "r"]
    header = (out / (default_prefix(SYSTEM, "pid").rstrip("_") + ".h")).read_text()
    assert "N_Y 7 " in header
    assert "y[0]  z: depth z from pressure; every 2 samples (0.2 s)" in header
    assert "y[6]  r: attitude phi theta psi and body rates p q r; every sample" in header
    with pytest.raises(Exception):
        ctl.step([0.0] * 12, 0.0)  # the full state is not what it takes
    _reproduces(ctl, run, r)


def test_exported_controller_tuned_with_latency(lagged_run, tmp_path):
    """A scenario with lagging sensors exports a controller whose header states the latency it was tuned with; it
    takes each reading as it arrives (the delay is in the plant: close_loop delays the readings as the run does)
    and reproduces the compiled run."""
    s, cfg, run, r = lagged_run
    out, mod, ctl = _export(cfg, tmp_path)
    assert mod.N_Y == 7
    header = (out / (default_prefix(SYSTEM, "pid").rstrip("_") + ".h")).read_text()
    assert ("y[0]  z: depth z from pressure; every 2 samples (0.2 s): read when round(t / SAMPLE_TIME) is a multiple "
            "of 2, ignored otherwise; tuned with a latency of 3 samples (0.3 s): pass the reading when it arrives") \
        in header
    assert "y[6]  r: attitude phi theta psi and body rates p q r; every sample; tuned with a latency of 1 sample (0.1 s)" in header
    _reproduces(ctl, run, r)


def test_a_short_study_with_imu_and_depth(tmp_path):
    """NSGA-II, 6 candidates, 2 generations on the BlueROV2 with only IMU and depth: it runs to its end; the
    AGSTA defaults score (1, 1) (f_rmse over z, phi, theta, psi: the x, y RMSE are 0 and left out)."""
    s, cfg = _base()
    cfg = replace(cfg, time_duration=10.0, **IMU_DEPTH)
    (tmp_path / "short.toml").write_text(cfg.to_toml(), encoding="utf-8")
    study = tiny_study("agsta", seed=5, population=6, generations=2, scale=3.0, include_table2=True, name="imu_depth")
    (tmp_path / "study.toml").write_text(study.replace(
        "[evaluation]\n", f'[evaluation]\nsystem = "{SYSTEM}"\nscenario = "short.toml"\n'), encoding="utf-8")
    assert cli.main(["tune", str(tmp_path / "study.toml"), "--out", str(tmp_path / "out")]) == 0
    c = ck.read_checkpoint(tmp_path / "out" / "front.h5")
    assert np.all(c.ref_rmse[0:2] == 0) and np.all(c.ref_rmse[2:6] > 0)
    np.testing.assert_allclose(c.table2_F, [1.0, 1.0], rtol=1e-12)
    fr = read_front(tmp_path / "out" / "front.h5")
    assert fr.size >= 1 and np.isfinite(fr.F).all()
