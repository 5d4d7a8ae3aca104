"""Logs in: mapping files, CSV and ROS 2 bags, frames, alignment, joint splines, bad logs.

References are independent of arvcas's own rotation code: SciPy's ``Rotation`` for quaternions and Euler
angles, NumPy's interpolation for alignment, the smoothing spline's known transfer function.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from arvcas.ident.logs import LogError, load_log

T = np.arange(0.0, 10.0 + 1e-9, 0.01)  # 100 Hz


def _csv(path: Path, header, cols, fmt="%.12g"):
    np.savetxt(path, np.stack(cols, axis=1), delimiter=",", header=",".join(header), comments="", fmt=fmt)


def _truth():
    """A tumbling attitude in NED/FRD whose yaw crosses +-180 deg, and a position."""
    e = np.stack([0.3 * np.sin(0.7 * T), 0.2 * np.cos(0.5 * T), 2.5 + 0.15 * T], axis=1)  # roll, pitch, yaw (rad)
    pos = np.stack([np.sin(0.3 * T), 0.5 * T, -1.0 + 0.1 * T], axis=1)
    return e, pos


def _write_log(d: Path, world="nwu", body="flu", extra_log="passive = true", mutate=None, order="xyzw"):
    """Pose (z-up world, FLU body: ROS conventions) and joints as CSV, and the mapping file."""
    e, pos = _truth()
    R_ned = Rotation.from_euler("ZYX", e[:, ::-1])  # body FRD -> world NED
    C = np.diag([1.0, -1.0, -1.0])
    Cw = {"nwu": C, "ned": np.eye(3)}[world]
    Cb = {"flu": C, "frd": np.eye(3)}[body]
    R_src = Rotation.from_matrix(Cw @ R_ned.as_matrix() @ Cb)
    q = R_src.as_quat()  # x, y, z, w
    if order == "wxyz":
        q = q[:, [3, 0, 1, 2]]
    p_src = pos @ Cw.T
    cols = [T, *p_src.T, *q.T]
    hdr = ["time_secs", "px", "py", "pz", "q0", "q1", "q2", "q3"]
    if mutate:
        cols = mutate(cols)
    _csv(d / "pose.csv", hdr, cols)
    tj = np.arange(0.0, 10.0 + 1e-9, 0.02)
    _csv(d / "joints.csv", ["time_secs", "a", "b"], [tj, 0.5 * np.sin(tj), 30.0 + 0 * tj])
    text = f'''[log]
name = "trial"
{extra_log}
rate = 50.0

[[stream]]
file = "pose.csv"
time = "time_secs"
world = "{world}"
body = "{body}"
quaternion_order = "{order}"
position = {{ columns = ["px", "py", "pz"], unit = "m" }}
quaternion = {{ columns = ["q0", "q1", "q2", "q3"] }}

[[stream]]
file = "joints.csv"
time = "time_secs"
[stream.joints]
q1 = {{ column = "a" }}
q2 = {{ column = "b", unit = "deg", offset = 0.1, sign = -1 }}
'''
    (d / "trial.log.toml").write_text(text)
    return d / "trial.log.toml"


@pytest.mark.parametrize("world,body,order", [("nwu", "flu", "xyzw"), ("ned", "frd", "wxyz")])
def test_frames_and_alignment(tmp_path, world, body, order):
    lg = load_log(_write_log(tmp_path, world, body, order=order), n_joints=2)
    e, pos = _truth()
    assert lg.dt == pytest.approx(0.02) and lg.t[0] == 0.0 and lg.duration == pytest.approx(10.0)
    ti = lg.t + lg.t0
    for k, s in enumerate(("roll", "pitch")):
        assert np.max(np.abs(lg.signals[s] - np.interp(ti, T, e[:, k]))) < 1e-6
    yaw_true = np.unwrap(np.interp(ti, T, e[:, 2]))
    assert np.max(np.abs(lg.signals["yaw"] - yaw_true)) < 1e-6  # crosses 180 deg without a jump
    assert np.max(np.abs(np.diff(lg.signals["yaw"]))) < 0.01
    for k, s in enumerate("xyz"):
        assert np.max(np.abs(lg.signals[s] - np.interp(ti, T, pos[:, k]))) < 1e-9


def test_joint_map_and_spline_cutoff(tmp_path):
    lg = load_log(_write_log(tmp_path), n_joints=2)
    q, qd, qdd = lg.joints(lg.t)
    # q2 = -(30 deg) + 0.1 rad, constant
    assert np.allclose(q[:, 1], 0.1 - math.radians(30.0), atol=1e-9) and np.allclose(qdd[:, 1], 0.0, atol=1e-9)
    mid = (lg.t > 1) & (lg.t < 9)  # 0.16 Hz, far below the 2 Hz cutoff: passed, derivatives right
    assert np.max(np.abs(qd[mid, 0] - 0.5 * np.cos(lg.t[mid] + lg.t0))) < 2e-3
    assert np.max(np.abs(qdd[mid, 0] + 0.5 * np.sin(lg.t[mid] + lg.t0))) < 2e-2


@pytest.mark.floor  # scipy's make_smoothing_spline (new in scipy 1.10, its floor)
def test_spline_halves_amplitude_at_cutoff(tmp_path):
    """The stated smoothing: a sinusoid at f_c comes out at half its amplitude (transfer 1 / (1 + lam dt w^4))."""
    fc, dt = 2.0, 0.01
    t = np.arange(0.0, 20.0, dt)
    _csv(tmp_path / "j.csv", ["t", "a"], [t, np.sin(2 * math.pi * fc * t)])
    _csv(tmp_path / "w.csv", ["t", "fx", "fy", "fz", "mx", "my", "mz"], [t, *(0 * t for _ in range(6))])
    (tmp_path / "m.log.toml").write_text('''[log]
joint_cutoff = 2.0
[[stream]]
file = "w.csv"
time = "t"
wrench = { columns = ["fx", "fy", "fz", "mx", "my", "mz"], unit = "N,N,N,N*m,N*m,N*m" }
[[stream]]
file = "j.csv"
time = "t"
joints = { q1 = { column = "a" } }
''')
    lg = load_log(tmp_path / "m.log.toml", n_joints=1)
    tt = np.arange(5.0, 15.0, 0.001)
    amp = np.sqrt(2 * np.mean(lg.joints(tt)[0][:, 0] ** 2))
    assert amp == pytest.approx(0.5, abs=0.02)


def _expect(tmp_path, match, **kw):
    with pytest.raises(LogError, match=match) as e:
        load_log(_write_log(tmp_path, **kw), n_joints=2)
    assert "\n" not in str(e.value)
    return str(e.value)


def _nan(cols):
    cols[1] = cols[1].copy()
    cols[1][300] = np.nan
    return cols


def _back(cols):
    cols[0] = cols[0].copy()
    cols[0][400] = cols[0][398]
    return cols


def _gap(cols):
    k = (T < 4.0) | (T > 5.5)
    return [c[k] for c in cols]


def test_bad_logs_one_line(tmp_path):
    msg = _expect(tmp_path, r"pose\.csv: column 'px': NaN", mutate=_nan)
    assert "row 302" in msg
    _expect(tmp_path, r"pose\.csv: column 'time_secs': time not increasing at row 402", mutate=_back)
    _expect(tmp_path, r"pose\.csv: column 'time_secs': a gap of 1\.5.* s after t = 3\.99 s \(allowed: 0\.5 s", mutate=_gap)
    # the body frame declared wrongly: the vehicle would be upside down
    _write_log(tmp_path)
    (tmp_path / "trial.log.toml").write_text((tmp_path / "trial.log.toml").read_text().replace('body = "flu"',
                                                                                                'body = "frd"'))
    with pytest.raises(LogError, match=r"frame does not match: median roll 1\d\d deg with body = \"frd\".*"
                                       r"body = \"flu\" gives \d+ deg"):
        load_log(tmp_path / "trial.log.toml", n_joints=2)


@pytest.mark.parametrize("edit,match", [
    (('unit = "m" }', 'unit = "furlong" }'), r"stream\[1\]\.position\.unit: unknown unit 'furlong' \(allowed for a length"),
    (('unit = "m" }', 'unit = "rad" }'), r"'rad' is not a unit of length"),
    (('"px"', '"pxx"'), r"pose\.csv: no column 'pxx' \(named in .*trial\.log\.toml\) \(did you mean 'px'\?\)"),
    (("passive = true", ""), r"no thrust, command or wrench stream: map one, or say \[log\] passive = true"),
    (('world = "nwu"', 'world = "up"'), r"stream\[1\]\.world: unknown world frame .up. \(allowed: ned, enu, nwu\)"),
    (('q2 = {', 'q3 = {'), r"joints\.q3: the system has joints q1\.\.q2"),
])
def test_bad_mappings_one_line(tmp_path, edit, match):
    p = _write_log(tmp_path)
    p.write_text(p.read_text().replace(*edit))
    with pytest.raises(LogError, match=match) as e:
        load_log(p, n_joints=2)
    assert "\n" not in str(e.value)


def test_rosbag_same_as_csv(tmp_path):
    """A ROS 2 bag (sqlite3 and MCAP) written with rosbags: PoseStamped and JointState mapped by field."""
    pytest.importorskip("rosbags")
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Pose, Header, Time = ts.types["geometry_msgs/msg/PoseStamped"], ts.types["std_msgs/msg/Header"], \
        ts.types["builtin_interfaces/msg/Time"]
    P, Q, Pt = ts.types["geometry_msgs/msg/Pose"], ts.types["geometry_msgs/msg/Quaternion"], \
        ts.types["geometry_msgs/msg/Point"]
    JS = ts.types["sensor_msgs/msg/JointState"]
    (tmp_path / "csv").mkdir()
    csv_log = load_log(_write_log(tmp_path / "csv"), n_joints=2)
    pose = np.loadtxt(tmp_path / "csv" / "pose.csv", delimiter=",", skiprows=1)
    joints = np.loadtxt(tmp_path / "csv" / "joints.csv", delimiter=",", skiprows=1)
    for storage in (StoragePlugin.SQLITE3, StoragePlugin.MCAP):
        bag = tmp_path / f"bag_{storage.name.lower()}"
        with Writer(bag, version=8, storage_plugin=storage) as w:
            cp = w.add_connection("/mocap/pose", Pose.__msgtype__, typestore=ts)
            cj = w.add_connection("/arm/joint_states", JS.__msgtype__, typestore=ts)
            for row in pose:
                sec = int(row[0])
                st = Time(sec=sec, nanosec=int(round((row[0] - sec) * 1e9)))
                msg = Pose(header=Header(stamp=st, frame_id="pool"),
                           pose=P(position=Pt(x=row[1], y=row[2], z=row[3]), orientation=Q(x=row[4], y=row[5], z=row[6],
                                                                                          w=row[7])))
                w.write(cp, int(row[0] * 1e9) + 1000, ts.serialize_cdr(msg, Pose.__msgtype__))
            for row in joints:
                sec = int(row[0])
                st = Time(sec=sec, nanosec=int(round((row[0] - sec) * 1e9)))
                msg = JS(header=Header(stamp=st, frame_id=""), name=["a", "b"], position=np.array(row[1:3]),
                         velocity=np.zeros(2), effort=np.zeros(2))
                w.write(cj, int(row[0] * 1e9) + 2000, ts.serialize_cdr(msg, JS.__msgtype__))
        (tmp_path / f"{bag.name}.log.toml").write_text(f'''[log]
name = "trial"
passive = true
rate = 50.0
bag = "{bag.name}"
[[stream]]
topic = "/mocap/pose"
time = "header.stamp"
world = "nwu"
body = "flu"
position = {{ columns = ["pose.position.x", "pose.position.y", "pose.position.z"], unit = "m" }}
quaternion = {{ columns = ["pose.orientation.x", "pose.orientation.y", "pose.orientation.z", "pose.orientation.w"] }}
[[stream]]
topic = "/arm/joint_states"
time = "header.stamp"
[stream.joints]
q1 = {{ column = "position[0]" }}
q2 = {{ column = "position[1]", unit = "deg", offset = 0.1, sign = -1 }}
''')
        lg = load_log(tmp_path / f"{bag.name}.log.toml", n_joints=2)
        assert lg.t0 == pytest.approx(csv_log.t0, abs=1e-9) and len(lg.t) == len(csv_log.t)
        for s in ("x", "y", "z", "roll", "pitch", "yaw", "q1", "q2"):
            assert np.max(np.abs(lg.signals[s] - csv_log.signals[s])) < 1e-9, (storage, s)
    bad = tmp_path / f"bag_{StoragePlugin.MCAP.name.lower()}.log.toml"
    bad.write_text(bad.read_text().replace('"/mocap/pose"', '"/mocap/posee"'))
    with pytest.raises(LogError, match=r"no topic '/mocap/posee'.*did you mean '/mocap/pose'"):
        load_log(bad, n_joints=2)
