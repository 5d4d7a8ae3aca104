"""The Hinsdale pool trials and the system that describes the vehicle as tested.

The shipped trials (studies/validation/hinsdale2023/) load as the data set wrote them, and the system
hinsdale_bluerov2_alpha5 reproduces the real vehicle's static attitude at every rest of those trials
(real data as the reference: docs/systems/hinsdale_bluerov2_alpha5.md §4.3).
"""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import fsolve

import arvcas
from script_helpers import load_script

DATA = Path(__file__).resolve().parents[1] / "studies" / "validation" / "hinsdale2023"
HEADERS = {
    "mocap": "time_secs,x_pose,y_pose,z_pose,x_ori,y_ori,z_ori,w_ori,roll,pitch,yaw",
    "imu": "time_secs,x_ori,y_ori,z_ori,w_ori,x_angvel,y_angvel,z_angvel,x_linacc,y_linacc,z_linacc",
    "joint_states": "time_secs,axis_a_pos,axis_b_pos,axis_c_pos,axis_d_pos,axis_e_pos,"
                    "axis_a_vel,axis_b_vel,axis_c_vel,axis_d_vel,axis_e_vel",
}


def _measure():
    return load_script(DATA / "measure.py", "hinsdale_measure")


M = _measure()
TRIALS = M.IDENTIFY + M.HELD_OUT + M.BASELINES


def test_shipped_trials_are_the_data_sets_files():
    """Every stream of every shipped trial: the upstream header, finite numbers, increasing time; the
    traj trials' start time and commanded trajectory; the licence notice; identification only on
    traj003-traj030 and disjoint from the held-out trials."""
    assert "Copyright (c) 2023 Hannah Kolano" in (DATA / "LICENSE").read_text(encoding="utf-8")
    assert set(M.IDENTIFY).isdisjoint(M.HELD_OUT)
    assert all("003-0" <= t[4:] <= "030-1" for t in M.IDENTIFY + M.HELD_OUT)
    for trial in TRIALS:
        for stream, header in HEADERS.items():
            with gzip.open(DATA / f"{trial}_{stream}.csv.gz", "rt") as fh:
                assert fh.readline().strip().startswith(header), (trial, stream)
            h, a = M.read(trial, stream)
            assert np.isfinite(a).all() and (np.diff(a[:, 0]) > 0).all() and len(a) > 300, (trial, stream)
        if trial.startswith("traj"):
            code = trial[4:]
            assert (DATA / f"metadata_{code}.yml").read_text().startswith("start_time: ")
            assert (DATA / "combo_traj_yaml_files_fullrange2" / f"traj{code[:3]}" / f"traj{code}.yaml").is_file()
    assert len(M.table().splitlines()) == 2 + 3 * len(TRIALS)
    assert sum(t.startswith("traj") for t in TRIALS) == len(M.IDENTIFY + M.HELD_OUT)  # their metadata was checked


def _rest_windows(trial: str):
    """(q = axis_e, d, c, b; IMU roll; IMU pitch) over the arm's still windows: before its first motion and
    from 4 s after its last (z-up angles as logged), at least 1.5 s long."""
    h, a = M.read(trial, "joint_states")
    t, q = a[:, 0], a[:, [h.index(f"axis_{j}_pos") for j in "edcb"]]
    hi, ai = M.read(trial, "imu")
    ti = ai[:, 0]
    roll, pitch = M.roll_pitch(hi, ai)
    moving = t[1:][np.abs(np.diff(q, axis=0)).max(axis=1) > 2e-3]
    spans = [(ti[0], ti[-1])] if len(moving) == 0 else [(max(ti[0], moving[0] - 3.0), moving[0] - 0.2),
                                                         (moving[-1] + 4.0, ti[-1])]
    out = []
    for lo, hi_ in spans:
        if hi_ - lo >= 1.5:
            s = (ti >= lo) & (ti <= hi_)
            out.append((q[(t >= lo) & (t <= hi_)].mean(axis=0), roll[s].mean(), pitch[s].mean()))
    return out


def test_static_attitude_at_rest_matches_the_trials():
    """The system's equilibrium attitude (uvms_rhs's roll and pitch accelerations zero, at rest, the logged
    joint angles as q without offsets) against the IMU at every rest of the shipped trials: the mount, the
    joint convention, the weights and buoyancies. On the 12 rest windows of the shipped trials (roll over
    16 deg, pitch over 12 deg): RMS 0.85 / 0.57 deg, means +0.27 / -0.32 deg, correlations 0.999 / 0.996; on
    all 57 trials of the data set (data sheet §4.3) 0.85 / 0.77 deg, while an arm hung upside down gives a
    roll correlation of -0.98."""
    s = arvcas.load_system("hinsdale_bluerov2_alpha5")
    assert (s.n_thrusters, s.n_joints, s.structure.arm, s.structure.arm_trim) == (8, 4, "chain", False)
    f = arvcas.dynamics("uvms_rhs", system=s)
    z4 = np.zeros(4)

    def ang_acc(a, q):
        x = np.zeros(12)
        x[3], x[4] = a
        return np.asarray(f(x, np.zeros(6), q, z4, z4, 0.0)).ravel()[9:11]

    meas, model = [], []
    for trial in TRIALS:
        for q, roll, pitch in _rest_windows(trial):
            phi, theta = fsolve(ang_acc, [roll, -pitch], args=(q,), xtol=1e-12)
            meas.append((roll, pitch))
            model.append((phi, -theta))  # NED pitch -> the logs' z-up pitch (+ nose down)
    meas, model = np.degrees(meas), np.degrees(model)
    assert len(meas) >= 10 and np.ptp(meas[:, 0]) > 8 and np.ptp(meas[:, 1]) > 6
    err = meas - model
    rms = np.sqrt((err ** 2).mean(axis=0))
    assert (rms < [1.2, 1.2]).all() and (np.abs(err.mean(axis=0)) < [0.5, 0.5]).all(), (rms, err.mean(axis=0))
    assert min(np.corrcoef(meas[:, k], model[:, k])[0, 1] for k in range(2)) > 0.98
    # the home pose (the stow pose): K24 measured roll 3.8, pitch 1.5 deg; the model 3.99, 1.39
    phi, theta = fsolve(ang_acc, [0.07, -0.02], args=(np.array([3.054, 0.0, 0.0, 1.61]),), xtol=1e-12)
    assert abs(np.degrees(phi) - 3.99) < 0.01 and abs(np.degrees(-theta) - 1.39) < 0.01
