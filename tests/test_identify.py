"""Identification and validation: sensitivities, synthetic truth and coverage,
unidentifiable parameters, the identified system file, the command line.

The synthetic truth is the Hinsdale vehicle without its arm (a vehicle-only system keeps the compiled code
small): released tilted, it rocks back under its restoring moments and damping, and the logs of it carry
white noise at stated levels (arvcas.ident.synthetic). The references are independent of the estimator:
central finite differences of the simulation, and the known parameters the logs were simulated with.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from ident_helpers import vehicle_only

import arvcas
from arvcas.cli import main
from arvcas.ident import identify as ident_mod
from arvcas.ident import logs, plant, synthetic, validate
from arvcas.ident.estimate import Z95
from arvcas.system import System

FREE = ("vehicle.zB", "vehicle.Ixx", "hydro.K_p", "hydro.M_q_absq")
TRUTH_CHANGE = {"vehicle.zB": -0.012, "vehicle.Ixx": 0.40, "hydro.K_p": -0.5, "hydro.M_q_absq": -3.0}
START = {"vehicle.zB": -0.02, "vehicle.Ixx": 0.30, "hydro.K_p": -0.2, "hydro.M_q_absq": -1.0}


@pytest.fixture(scope="module")
def vehicle(tmp_path_factory):
    """The Hinsdale vehicle without its arm, as a system file; and that system with the 'true' parameters."""
    sys_ = vehicle_only("hinsdale_bluerov2_alpha5", "hinsdale_vehicle", tmp_path_factory.mktemp("vehicle"))
    return sys_, System(sys_.params.replace(TRUTH_CHANGE))


def _trials(d, truth, seeds, duration=12.0):
    return [synthetic.write_trial(d, f"s{k}", truth, duration=duration, seed=k, p=truth.params.vector())
            for k in seeds]


def test_sensitivities_match_finite_differences(vehicle, tmp_path):
    _, truth = vehicle
    lg = logs.load_log(_trials(tmp_path, truth, [0], duration=4.0)[0], n_joints=0)
    pl = plant.LogPlant(truth, m=2, free=FREE)
    p = truth.params.vector()
    th = np.array([truth.params[n] for n in FREE])
    x0 = validate.initial_state(lg) + np.r_[0, 0, 0, 0, 0, 0, 0.01, -0.02, 0.03, 0.05, -0.04, 0.02]
    X, dX = plant.simulate_sens(pl, lg, x0, p, th)
    assert np.array_equal(X, plant.simulate(pl, lg, x0, p))
    idx = [truth.layout.index[n] for n in FREE]
    z = np.r_[x0, th]
    for j in (3, 4, 8, 10, 12, 13, 14, 15):
        eps = 1e-6 * max(1.0, abs(z[j]))

        def sim(zz):
            pv = p.copy()
            pv[idx] = zz[12:]
            return plant.simulate(pl, lg, zz[:12], pv)

        zp, zm = z.copy(), z.copy()
        zp[j] += eps
        zm[j] -= eps
        fd = (sim(zp) - sim(zm)) / (2 * eps)
        assert np.max(np.abs(fd - dX[:, :, j])) <= 1e-6 * max(1.0, np.max(np.abs(fd))), j


def test_recovery_and_coverage(vehicle, tmp_path):
    """20 noise seeds: every estimate near the truth, the 95 % intervals cover it about 95 % of the time."""
    model, truth = vehicle
    start = System(model.params.replace(START))
    truth_v = np.array([truth.params[n] for n in FREE])
    z, cover = [], []
    for seed in range(20):
        paths = _trials(tmp_path / f"seed{seed}", truth, [2 * seed, 2 * seed + 1], duration=10.0)
        est = ident_mod.identify(start, logs.load_logs(paths, n_joints=0), FREE, threads=1)
        assert est.identifiable.all() and not est.unidentifiable, est.report()
        assert 0.5 < est.s2 < 2.0  # the stated noise is the noise: s^2 near 1
        zs = (est.values - truth_v) / est.std
        z.append(zs)
        cover.append(np.abs(zs) <= Z95)
    z, cover = np.array(z), np.array(cover)
    assert np.all(np.abs(z) < 5), z  # recovered, within a few standard errors
    assert cover.mean() >= 0.85, (cover.mean(), z)  # 80 intervals: 95 % expected, 85 % is 4 sd below
    assert 0.6 < np.std(z) < 1.6, np.std(z)  # the stated standard errors are the real ones


def test_unexcited_parameter_is_named(vehicle, tmp_path):
    model, truth = vehicle
    paths = _trials(tmp_path, truth, [0], duration=6.0)
    free = ("vehicle.zB", "thrusters.T1.u_max")  # the thrusters are off: T1's limit has no effect
    est = ident_mod.identify(model, logs.load_logs(paths, n_joints=0), free, threads=1)
    assert list(est.identifiable) == [True, False]
    assert math.isnan(est.std[1]) and "thrusters.T1.u_max: the trials carry no information" in est.report()
    assert "not identifiable" in est.report()


def test_identified_file_round_trip_and_cli(vehicle, tmp_path, capsys):
    model, truth = vehicle
    paths = _trials(tmp_path / "logs", truth, [5, 6], duration=8.0)
    out = tmp_path / "out" / "identified.toml"
    out.parent.mkdir()
    rc = main(["identify", "--system", model.path, "--free", ",".join(FREE), *map(str, paths), "--out", str(out),
               "--threads", "1"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "iteration   0" in text and "95 % interval" in text
    ident = arvcas.load_system(out)
    assert ident.name == "hinsdale_vehicle_identified"
    for n in FREE:  # estimated, near the truth, sourced from the trials
        assert ident.params[n] == pytest.approx(truth.params[n], rel=0.2), n
        assert "identified by arvcas identify" in ident.params.source(n) and "s5, s6" in ident.params.source(n)
    same = [n for n in model.params.names() if n not in FREE]
    assert np.array_equal([ident.params[n] for n in same], [model.params[n] for n in same])
    # validation with it: validation.json has its documented shape (docs/identification.md), in SI
    vd = tmp_path / "val"
    assert main(["validate", "--system", str(out), str(paths[0]), "--out", str(vd), "--figures"]) == 0
    doc = json.loads((vd / "validation.json").read_text())
    assert doc["system"] == "hinsdale_vehicle_identified"
    m = doc["trials"]["s5"]
    for key in ("rmse", "nrmse", "r2", "max_error"):
        assert set(m[key]) == {"x", "y", "z", "roll", "pitch", "yaw", "p", "q", "r"}
    assert m["rmse"]["roll"] < 3 * synthetic.NOISE["attitude"] and m["r2"]["pitch"] > 0.9
    assert m["role"] == "fit" and set(doc["summary"]) == {"fit"}  # its sources name the trials it was fitted on
    assert (vd / "s5.png").stat().st_size > 0 and "s5" in (vd / "README.md").read_text()


@pytest.mark.parametrize("args,match", [
    (["--free", "vehicle.zBB"], "--free: hinsdale_vehicle has no parameter 'vehicle.zBB'.*vehicle.zB"),
    (["--free", "vehicle.zB", "--max-iter", "0"], "--max-iter: must be in"),
])
def test_identify_refuses_before_work(vehicle, tmp_path, capsys, args, match):
    model, truth = vehicle
    paths = _trials(tmp_path, truth, [0], duration=2.0)
    out = tmp_path / "o.toml"
    rc = main(["identify", "--system", model.path, *args, str(paths[0]), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and __import__("re").search(match, err), err
    assert not out.exists()


def test_validate_refuses_a_bad_log_before_writing(vehicle, tmp_path, capsys):
    model, truth = vehicle
    good, bad = _trials(tmp_path, truth, [0, 1], duration=2.0)
    imu = tmp_path / "s1_imu.csv"
    rows = imu.read_text().splitlines()
    rows[40] = rows[40].replace(rows[40].split(",")[1], "nan", 1)
    imu.write_text("\n".join(rows) + "\n")
    rc = main(["validate", "--system", model.path, str(good), str(bad), "--out", str(tmp_path / "v")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "s1_imu.csv: column 'wx': NaN or infinite value at row 41" in err
    assert not (tmp_path / "v").exists()


def test_log_plant_against_scipy_on_a_real_trial():
    """The log-driven plant (RK4, joints from the log's splines at every stage) against SciPy's DOP853 of the
    public ``uvms_rhs`` with the same joint functions of time: the Hinsdale vehicle and arm, 4 s of traj005-0."""
    from scipy.integrate import solve_ivp

    system = arvcas.load_system("hinsdale_bluerov2_alpha5")
    path = Path(__file__).resolve().parents[1] / "studies" / "validation" / "hinsdale2023" / "traj005-0.log.toml"
    lg = logs.load_log(path, system.n_joints)
    lg = lg.window(5.0, 9.0)  # the arm moves
    x0 = validate.initial_state(lg)
    f = arvcas.dynamics("uvms_rhs", system)
    zero6 = np.zeros(6)

    def rhs(t, x):
        q, qd, qdd = lg.joints(np.array([t]))
        return f(x, zero6, q[0], qd[0], qdd[0], np.zeros(1)).reshape(-1)

    ref = solve_ivp(rhs, (0.0, lg.t[-1]), x0, method="DOP853", t_eval=lg.t, rtol=1e-11, atol=1e-12).y.T
    errs = []
    for h, tol in ((0.02, 3e-5), (0.005, 2e-6)):
        X = plant.simulate(plant.LogPlant(system, m=validate.substeps(lg.dt, h)), lg, x0, system.params.vector())
        errs.append(np.max(np.abs(X - ref)))
        assert errs[-1] < tol, (h, np.max(np.abs(X - ref), axis=0))
    # the joint accelerations of a cubic smoothing spline are piecewise linear (kinks at every joint sample,
    # 18 ms apart): the right-hand side is not smooth in time, and RK4 converges at second order here (a
    # quarter of the step, 1/16 of the error; measured 13x)
    assert errs[0] / errs[1] > 8, errs
    assert np.max(np.abs(ref[:, 3:5] - ref[0, 3:5])) > 0.01  # the trial did move the vehicle


def test_ctrl_c_keeps_the_best_iterate(vehicle, tmp_path):
    """SIGINT during `arvcas identify`: it stops after the current iteration and writes the best iterate."""
    import os
    import signal
    import subprocess
    import sys

    model, truth = vehicle
    start = tmp_path / "start.toml"
    start.write_text(open(model.path, encoding="utf-8").read())
    paths = _trials(tmp_path / "logs", truth, [7, 8], duration=8.0)
    out = tmp_path / "id.toml"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(__import__("pathlib").Path(arvcas.__file__).parents[1]),
                                                       os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-m", "arvcas.cli", "identify", "--system", str(start), "--free",
                             ",".join(FREE), *map(str, paths), "--out", str(out), "--threads", "1", "--max-iter", "500"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if line.startswith("iteration   1"):
            proc.send_signal(signal.SIGINT)
            break
    rest, err = proc.communicate(timeout=300)
    text = "".join(lines) + rest
    assert proc.returncode == 130, (text, err)
    assert "interrupted" in text and out.exists()
    ident = arvcas.load_system(out)
    assert ident.params["vehicle.zB"] != model.params["vehicle.zB"]  # the best iterate, not the start
