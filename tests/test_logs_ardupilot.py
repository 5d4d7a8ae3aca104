"""ArduPilot logs (DataFlash .bin, MAVLink .tlog) and ROS 1 bags through the ``*.log.toml`` mapping.

The logs are written here: a DataFlash file byte by byte in ArduPilot's format (pymavlink reads DataFlash
but writes none: FMT messages, then data, each ``0xA3 0x95 <id> <payload>``), a telemetry log with
pymavlink's own MAVLink encoder (8-byte big-endian wall-clock time, then the packet, as QGroundControl
writes it), a ROS 1 bag with rosbags' writer. Each is read back through arvcas.ident.logs.load_log and
checked on values known by construction: angles, depth from a known pressure, which PWM drives which
thruster, the segment's cut times on the boot clock.
"""

from __future__ import annotations

import math
import struct
import sys

import numpy as np
import pytest

from arvcas.ident import logs

pymavlink = pytest.importorskip("pymavlink")

RHO, P0, G0 = 1025.0, 101325.0, 9.80665
THRUSTERS = tuple(f"T{k}" for k in range(1, 9))
MANUAL, STABILIZE = 19, 0  # ArduSub's mode numbers (pymavlink's mavutil.mode_mapping_sub)


# ---- a DataFlash writer (the format: ArduPilot libraries/AP_Logger/LogStructure.h) ------------------------------

_STRUCT = {"B": "B", "b": "b", "H": "H", "h": "h", "I": "I", "i": "i", "f": "f", "Q": "Q", "q": "q", "n": "4s",
           "N": "16s", "Z": "64s", "c": "h", "C": "H", "M": "b"}
_SCALE = {"c": 100.0, "C": 100.0}  # centi-units: the file holds value * 100


class DataFlash:
    def __init__(self):
        self.fmts: dict[str, tuple[int, str, list[str]]] = {}
        self.out = bytearray()
        self._fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")

    def _size(self, fmt: str) -> int:
        return 3 + struct.calcsize("<" + "".join(_STRUCT[c] for c in fmt))

    def _fmt(self, mid: int, name: str, fmt: str, cols: str) -> None:
        self.fmts[name] = (mid, fmt, cols.split(","))
        if name != "FMT":
            self.write("FMT", mid, self._size(fmt), name.encode(), fmt.encode(), cols.encode())
        else:
            self.out += bytes([0xA3, 0x95, 128]) + struct.pack("<BB4s16s64s", 128, self._size(fmt), b"FMT",
                                                              fmt.encode(), cols.encode())

    def define(self, name: str, fmt: str, cols: str) -> None:
        self._fmt(len(self.fmts), name, fmt, cols)

    def write(self, name: str, *values) -> None:
        mid, fmt, _ = self.fmts[name]
        vals = [int(round(v * _SCALE[c])) if c in _SCALE else v for c, v in zip(fmt, values)]
        self.out += bytes([0xA3, 0x95, mid]) + struct.pack("<" + "".join(_STRUCT[c] for c in fmt), *vals)


def _roll(t):
    return 10.0 * np.sin(0.5 * t)  # deg


def _pitch(t):
    return -5.0 * np.cos(0.3 * t)


def _yaw(t):
    return 30.0 + 20.0 * t  # deg, logged in [0, 360): wraps at t = 16.5 s


def _depth(t):
    return 1.0 + 0.2 * np.sin(0.4 * t)  # m


def _pwm(t, k):
    """Channel k's PWM: a distinct staircase per channel (1500 + 10 k + 40 per 0.5 s step, k = 1 .. 8)."""
    return 1500.0 + 10.0 * k + 40.0 * (np.floor(t / 0.5) % 3)


def write_bin(path, arming=(("ARM", 5.0, 1), ("MODE", 12.0, STABILIZE), ("ARM", 20.0, 0), ("ARM", 24.0, 1),
                            ("ARM", 28.0, 0)), duration=30.0, units=True, ev=False):
    """An ArduSub-like DataFlash log of ``duration`` s: ATT 25 Hz, IMU (2 instances) and RCOU 50 Hz, BARO
    (instance 0 internal, 1 the external depth sensor) 10 Hz, MODE MANUAL at 0.5 s, the given arming."""
    df = DataFlash()
    df.define("UNIT", "QbZ", "TimeUS,Id,Label")
    df.define("FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds")
    df.define("PARM", "QNf", "TimeUS,Name,Value")
    df.define("MODE", "QMBB", "TimeUS,Mode,ModeNum,Rsn")
    df.define("ARM", "QBIBB", "TimeUS,ArmState,ArmChecks,Forced,Method")
    df.define("EV", "QB", "TimeUS,Id")
    df.define("ATT", "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF")
    df.define("IMU", "QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
    df.define("BARO", "QBffcf", "TimeUS,I,Alt,Press,Temp,CRt")
    df.define("RCOU", "Q" + "H" * 14, "TimeUS," + ",".join(f"C{k}" for k in range(1, 15)))
    if units:  # what ArduPilot writes: unit labels, then each message's unit ids ('#': its instance field)
        for uid, label in (("s", "s"), ("d", "deg"), ("E", "rad/s"), ("o", "m/s/s"), ("P", "Pa"), ("m", "m"),
                           ("Y", "us"), ("#", "instance"), ("-", "")):
            df.write("UNIT", 0, ord(uid), label.encode())
        for name, ids in (("ATT", "sdddddd---"), ("IMU", "s#EEEooo"), ("BARO", "s#mPOn"), ("RCOU", "s" + "Y" * 14)):
            df.write("FMTU", 0, df.fmts[name][0], ids.encode(), b"-" * len(ids))
    for ch in range(1, 15):  # outputs 1-8: motors 1-8 (SERVOn_FUNCTION 33-40), 9: lights (181), others unused
        fn = 32 + ch if ch <= 8 else (181 if ch == 9 else 0)
        df.write("PARM", 1000, f"SERVO{ch}_FUNCTION".encode(), float(fn))
    events = sorted([("MODE", 0.5, MANUAL), *arming], key=lambda e: e[1])
    armed = False
    for k in range(int(duration * 50) + 1):
        t = k / 50.0
        us = int(round(t * 1e6)) + 7  # the boot clock in us (not a multiple of the 20 ms grid)
        while events and events[0][1] <= t:
            kind, _, val = events.pop(0)
            if kind == "MODE":
                df.write("MODE", us - 3, val, val, 1)
            elif ev:
                df.write("EV", us - 3, 10 if val else 11)
            else:
                df.write("ARM", us - 3, val, 0, 0, 0)
            armed = bool(val) if kind == "ARM" else armed
        if k % 2 == 0:
            y = _yaw(t) % 360.0
            df.write("ATT", us, 0.0, _roll(t), 0.0, _pitch(t), 0.0, y, 0.0, 0.0, 0)
        for inst in (0, 1):
            df.write("IMU", us + inst, inst, 0.01, 0.02 * inst, 0.03, 0.1, 0.0, -9.8)
        if k % 5 == 0:
            df.write("BARO", us + 2, 0, 0.0, 99000.0, 25.0, 0.0)
            df.write("BARO", us + 3, 1, -_depth(t), P0 + RHO * G0 * _depth(t), 12.0, 0.0)
        df.write("RCOU", us + 4, *[int(_pwm(t, c)) if (armed and c <= 8) else (1500 if c <= 8 else 1100)
                                   for c in range(1, 15)])
    path.write_bytes(bytes(df.out))
    return path


BIN_STREAMS = """
[[stream]]
message = "ATT"
euler = { columns = ["Roll", "Pitch", "Yaw"], unit = "deg" }

[[stream]]
message = "BARO"
instance = 1
pressure = { columns = ["Press"], unit = "Pa" }
density = 1025.0
surface_pressure = 101325.0

[[stream]]
message = "IMU"
instance = 0
angular_velocity = { columns = ["GyrX", "GyrY", "GyrZ"], unit = "rad/s" }
acceleration = { columns = ["AccX", "AccY", "AccZ"], unit = "m/s^2" }

[[stream]]
message = "RCOU"
outputs = ["T1", "T2", "T3", "T4", "T5", "T6", "T7", "T8"]
"""


def _mapping(d, name, log_file, head="", streams=BIN_STREAMS):
    path = d / f"{name}.log.toml"
    path.write_text(f'[log]\nname = "{name}"\nardupilot = "{log_file}"\n{head}\n{streams}')
    return path


@pytest.fixture(scope="module")
def binlog(tmp_path_factory):
    d = tmp_path_factory.mktemp("bin")
    write_bin(d / "00000042.BIN")
    return d


def _load(path, **kw):
    return logs.load_log(path, n_joints=0, thruster_names=kw.get("thrusters", THRUSTERS))


def test_dataflash_values_segment_and_boot_clock(binlog):
    lg = _load(_mapping(binlog, "seg1", "00000042.BIN", "segment_index = 1"))
    # the first armed segment: 5 s to 20 s on the boot clock (ARM at 5 s + 7 us - 3 us)
    assert lg.t0 == pytest.approx(5.000004, abs=1e-9) and lg.duration == pytest.approx(15.0, abs=0.02)
    assert lg.segment.startswith("5.000-20.000 s (MANUAL, STABILIZE)")
    tb = lg.t0 + lg.t  # the boot clock
    assert np.max(np.abs(np.degrees(lg.signals["roll"]) - _roll(tb))) < 0.01
    assert np.max(np.abs(np.degrees(lg.signals["pitch"]) - _pitch(tb))) < 0.01
    yaw = np.degrees(lg.signals["yaw"])
    assert np.max(np.abs(np.diff(yaw))) < 1.0  # unwrapped across 360 -> 0 at 16.5 s
    assert np.max(np.abs((yaw - _yaw(tb) + 180.0) % 360.0 - 180.0)) < 0.01
    # depth from the external sensor's pressure, (p - p0) / (rho g): BARO at 10 Hz, linearly interpolated
    # (at most dt^2 / 8 max|d''| = 4.0e-5 m), float32 pressure (0.008 Pa steps: 8e-7 m)
    assert np.max(np.abs(lg.signals["z"] - _depth(tb))) < 4.2e-5
    assert np.allclose(lg.signals["p"], 0.01) and np.allclose(lg.signals["q"], 0.0)  # instance 0, not 1
    # channel k drives thruster Tk: each held from its message (logged 11 us after each 20 ms tick; the one
    # before the first armed tick is still the disarmed 1500 us)
    for k in range(1, 9):
        want = np.where(tb - 11e-6 < 5.0, 1500.0, _pwm(tb - 11e-6, k))
        assert want[0] == 1500.0 and np.array_equal(lg.command[f"T{k}"], want), k
        assert lg.command_unit[f"T{k}"] == "us"


def test_dataflash_segments_by_mode_and_index(binlog):
    lg = _load(_mapping(binlog, "stab", "00000042.BIN", 'modes = ["STABILIZE"]\nsegment_index = 1'))
    assert lg.t0 == pytest.approx(12.000004, abs=1e-9)
    assert lg.duration == pytest.approx(8.0, abs=0.02)
    lg = _load(_mapping(binlog, "seg2", "00000042.BIN", "segment_index = 2"))
    assert lg.t0 == pytest.approx(24.000004, abs=1e-9) and lg.duration == pytest.approx(4.0, abs=0.02)
    lg = _load(_mapping(binlog, "man", "00000042.BIN", 'modes = ["MANUAL"]'))  # one segment: no index needed
    assert lg.t0 == pytest.approx(5.000004, abs=1e-9) and lg.duration == pytest.approx(7.0, abs=0.02)
    lg = _load(_mapping(binlog, "all", "00000042.BIN", 'segment = "all"'))
    assert lg.t0 == pytest.approx(0.000011, abs=1e-9)  # the streams' latest start (RCOU)
    assert lg.duration == pytest.approx(30.0, abs=0.02)


def test_dataflash_ev_events_and_no_units(tmp_path):
    """Older logs: arming as EV events 10/11, no FMTU units; the cut is the same."""
    write_bin(tmp_path / "old.bin", arming=(("ARM", 3.0, 1), ("ARM", 9.0, 0)), duration=10.0, units=False, ev=True)
    lg = _load(_mapping(tmp_path, "old", "old.bin"))
    assert lg.t0 == pytest.approx(3.000004, abs=1e-9) and lg.duration == pytest.approx(6.0, abs=0.02)


@pytest.mark.parametrize("head, streams, message", [
    ("segment_index = 1", BIN_STREAMS.replace('"ATT"', '"ATTX"'), "no message 'ATTX' (named in"),
    ("segment_index = 1", BIN_STREAMS.replace('"Roll"', '"Rol"'), "message ATT has no field 'Rol' (named in"),
    ("segment_index = 1", BIN_STREAMS.replace("instance = 0\n", ""), "message IMU has instances 0, 1: say which"),
    ("segment_index = 1", BIN_STREAMS.replace("instance = 0\n", "instance = 4\n"), "has no instance 4 (it has 0, 1"),
    ("", BIN_STREAMS, "2 segments armed in 00000042.BIN (1: 5.000-20.000 s (MANUAL, STABILIZE); 2: 24.000-28.000 s"),
    ("segment_index = 3", BIN_STREAMS, "[log] segment_index = 3, but 00000042.BIN has 2 segment(s) armed"),
    ('modes = ["AUTO"]', BIN_STREAMS, "no segment armed in AUTO (modes logged: MANUAL, STABILIZE)"),
    ("segment_index = 1", BIN_STREAMS.replace('unit = "deg"', 'unit = "rad"'),
     "stream[1].euler.unit: ATT.Roll is in deg (the log says so), mapped as 'rad'"),
    ("segment_index = 1", BIN_STREAMS.replace('"T7", "T8"', '"", ""'),
     "stream[4].outputs: the system's thrusters T7, T8 are driven by no output channel"),
    ("segment_index = 1", BIN_STREAMS.replace('"T8"]', '"T8", "T9"]'), "outputs.T9: the system has no thruster 'T9'"),
    ("segment_index = 1", BIN_STREAMS.replace('"T8"]', '"T8", "T8"]'),
     "thruster 'T8' is driven by two channels (8, 9)"),
    ("segment_index = 1", BIN_STREAMS.replace("density = 1025.0\n", ""),
     "stream[2].density: depth from pressure needs the water's density"),
    ("segment_index = 1", BIN_STREAMS.replace('message = "ATT"', 'message = "ATT"\ntime = "TimeUS"'),
     "stream[1].time: an ArduPilot message's time is the autopilot's boot clock"),
    ("segment_index = 1", BIN_STREAMS.replace('message = "RCOU"', 'message = "IMU"\ninstance = 1'),
     "stream[4].outputs: names the output channels of RCOU or SERVO_OUTPUT_RAW"),
])
def test_dataflash_refusals(binlog, head, streams, message):
    with pytest.raises(logs.LogError) as e:
        _load(_mapping(binlog, "bad", "00000042.BIN", head, streams))
    assert message in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_unmapped_motor_and_no_arming(binlog, tmp_path):
    # a six-thruster system flying the eight-motor log: outputs 7 and 8 are motors the mapping leaves out
    six = BIN_STREAMS.replace(', "T7", "T8"]', "]")
    with pytest.raises(logs.LogError, match=r"outputs: channel 7 is the autopilot's motor 7 \(SERVO7_FUNCTION = 39\) "
                                            r"but drives no thruster"):
        _load(_mapping(binlog, "six", "00000042.BIN", "segment_index = 1", six), thrusters=THRUSTERS[:6])
    lights = BIN_STREAMS.replace('"T8"]', '"T8", "T9"]')  # channel 9 is the lights (SERVO9_FUNCTION = 181)
    with pytest.raises(logs.LogError, match="channel 9 drives thruster 'T9', but the log's SERVO9_FUNCTION = 181 is "
                                            "not a motor"):
        _load(_mapping(binlog, "lights", "00000042.BIN", "segment_index = 1", lights), thrusters=THRUSTERS + ("T9",))
    write_bin(tmp_path / "bench.bin", arming=(), duration=3.0)
    with pytest.raises(logs.LogError, match="no arming is logged .*say \\[log\\] segment = \"all\""):
        _load(_mapping(tmp_path, "bench", "bench.bin"))
    (tmp_path / "junk.bin").write_bytes(b"\x00" * 100)
    with pytest.raises(logs.LogError, match="junk.bin: no message 'ATT'"):
        _load(_mapping(tmp_path, "junk", "junk.bin"))
    (tmp_path / "flight.csv").write_text("t\n")
    with pytest.raises(logs.LogError, match="not an ArduPilot log: the file name ends in .bin"):
        _load(_mapping(tmp_path, "csv", "flight.csv"))


def test_missing_pymavlink_is_one_line(binlog, monkeypatch):
    monkeypatch.setitem(sys.modules, "pymavlink", None)
    with pytest.raises(logs.LogError, match=r"needs the pymavlink package: pip install 'arvcas\[ardupilot\]'$"):
        _load(_mapping(binlog, "nopm", "00000042.BIN", "segment_index = 1"))


# ---- MAVLink telemetry (.tlog) ----------------------------------------------------------------------------


WALL0 = 1.7e9  # the ground station's wall clock at the autopilot's boot (s): not the log's time base


class Tlog:
    def __init__(self, path):
        from pymavlink.dialects.v20 import ardupilotmega as mav

        self.mav = mav
        self.f = open(path, "wb")
        self.vehicle = mav.MAVLink(None, srcSystem=1, srcComponent=1)
        self.gcs = mav.MAVLink(None, srcSystem=255, srcComponent=190)

    def send(self, boot: float, msg, gcs=False) -> None:
        buf = msg.pack(self.gcs if gcs else self.vehicle)
        self.f.write(struct.pack(">Q", int((WALL0 + boot + 0.05) * 1e6)) + buf)  # received 50 ms later

    def heartbeat(self, boot: float, armed: bool, mode: int) -> None:
        m = self.mav
        self.send(boot, m.MAVLink_heartbeat_message(m.MAV_TYPE_GCS, m.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3), gcs=True)
        self.send(boot, m.MAVLink_heartbeat_message(m.MAV_TYPE_SUBMARINE, m.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                    m.MAV_MODE_FLAG_SAFETY_ARMED * armed, mode, 4, 3))


def write_tlog(path, X, C, t_boot, t_arm, t_disarm, pre=1.0):
    """A telemetry log: before ``t_arm`` the vehicle at X[0] and PWM 1500, from it ATTITUDE, SCALED_PRESSURE2,
    LOCAL_POSITION_NED and SERVO_OUTPUT_RAW (channel k: C[:, k - 1]) at 50 Hz on the boot clock ``t_boot``."""
    tl = Tlog(path)
    m = tl.mav
    for ch in range(1, 9):
        tl.send(0.0, m.MAVLink_param_value_message(f"SERVO{ch}_FUNCTION".encode(), 32.0 + ch, 9, 300, ch))
    times = np.r_[t_boot[0] - pre + np.arange(int(pre * 50)) / 50.0, t_boot]
    rows = np.r_[np.repeat(X[:1], int(pre * 50), axis=0), X]
    cmds = np.r_[np.full((int(pre * 50), C.shape[1]), 1500.0), C]
    next_hb = 0.0
    for t, x, c in zip(times, rows, cmds):
        ms = int(round(t * 1000))
        tl.send(t, m.MAVLink_attitude_message(ms, *x[3:6], *x[9:12]))
        z = x[2]
        tl.send(t, m.MAVLink_scaled_pressure2_message(ms, (P0 + RHO * G0 * z) / 100.0, 0.0, 1500))
        tl.send(t, m.MAVLink_local_position_ned_message(ms, *x[0:3], 0.0, 0.0, 0.0))
        tl.send(t, m.MAVLink_servo_output_raw_message(int(round(t * 1e6)), 0, *[int(v) for v in c[:8]]))
        tl.send(t, m.MAVLink_scaled_imu2_message(ms, 0, 0, -1000, 0, 0, 0, 0, 0, 0))
        if t >= next_hb - 1e-9 or abs(t - t_arm) < 1e-9 or abs(t - t_disarm) < 1e-9:
            tl.heartbeat(t, t_arm - 1e-9 <= t < t_disarm - 1e-9, MANUAL)
            next_hb = t + 1.0
    tl.f.close()
    return path


TLOG_STREAMS = """
[[stream]]
message = "ATTITUDE"
euler = { columns = ["roll", "pitch", "yaw"], unit = "rad" }

[[stream]]
message = "SCALED_PRESSURE2"
pressure = { columns = ["press_abs"], unit = "hPa" }
density = 1025.0
surface_pressure = 101325.0

[[stream]]
message = "SCALED_IMU2"
acceleration = { columns = ["xacc", "yacc", "zacc"], unit = "mG" }

[[stream]]
message = "SERVO_OUTPUT_RAW"
outputs = ["T1", "T2", "T3", "T4", "T5", "T6", "T7", "T8"]
"""


PRESSURE = """
[[stream]]
message = "SCALED_PRESSURE2"
pressure = { columns = ["press_abs"], unit = "hPa" }
density = 1025.0
surface_pressure = 101325.0
"""
POSITION = """
[[stream]]
message = "LOCAL_POSITION_NED"
position = { columns = ["x", "y", "z"], unit = "m" }
"""


def _X(t):
    X = np.zeros((len(t), 12))
    X[:, 0], X[:, 1], X[:, 2] = 0.1 * t, -0.05 * t, _depth(t)
    X[:, 3], X[:, 4], X[:, 5] = np.radians(_roll(t)), np.radians(_pitch(t)), np.radians(_yaw(t) % 360.0 - 180.0)
    return X


def test_tlog_values_and_heartbeat_segment(tmp_path):
    tb = 3.0 + np.arange(501) / 50.0  # boot 3 .. 13 s
    C = np.stack([_pwm(tb, k) for k in range(1, 9)], axis=1)
    write_tlog(tmp_path / "flight.tlog", _X(tb), C, tb, t_arm=4.0, t_disarm=12.0)
    lg = _load(_mapping(tmp_path, "tl", "flight.tlog", "", TLOG_STREAMS))
    # armed at the heartbeat of boot 4.0 s, disarmed at 12.0 s: the boot clock, not the wall clock
    assert lg.t0 == pytest.approx(4.0, abs=1e-9) and lg.duration == pytest.approx(8.0, abs=1e-9)
    t = lg.t0 + lg.t
    X = _X(t)
    for i, s in ((2, "z"), (3, "roll"), (4, "pitch")):
        assert np.max(np.abs(lg.signals[s] - X[:, i])) < 2e-6, s  # float32 hPa: 1.2e-4 hPa is 1.2e-6 m
    assert np.max(np.abs((lg.signals["yaw"] - X[:, 5] + math.pi) % (2 * math.pi) - math.pi)) < 1e-6
    for k in range(1, 9):
        assert np.array_equal(lg.command[f"T{k}"], _pwm(t, k)), k
    lg = _load(_mapping(tmp_path, "tl", "flight.tlog", "", TLOG_STREAMS.replace(PRESSURE, POSITION)))
    for i, s in enumerate(("x", "y", "z")):
        assert np.max(np.abs(lg.signals[s] - _X(lg.t0 + lg.t)[:, i])) < 1e-6, s
    # a damaged stretch (17 bytes of noise between two records): pymavlink's robust parser reads the file
    raw = (tmp_path / "flight.tlog").read_bytes()
    cut = len(raw) // 2
    cut = raw.index(struct.pack(">Q", int((WALL0 + 8.0 + 0.05) * 1e6))[:5], cut - 20000)
    (tmp_path / "damaged.tlog").write_bytes(raw[:cut] + bytes(range(3, 20)) + raw[cut:])
    from arvcas.ident import ardupilot

    # the scan ends at the end of the data (framed throughout) or at -1 (the byte after a frame is no frame)
    assert list(ardupilot._tlog_frames(raw))[-1] == len(raw)
    assert list(ardupilot._tlog_frames(raw[:cut] + b"\x03" + raw[cut:]))[-1] == -1
    lg2 = _load(_mapping(tmp_path, "dmg", "damaged.tlog", "", TLOG_STREAMS))
    assert lg2.t0 == lg.t0 and np.max(np.abs(lg2.signals["roll"] - X[:, 3])) < 1e-3


def test_tlog_refusals(tmp_path):
    tb = np.arange(101) / 50.0
    C = np.full((101, 8), 1500.0)
    write_tlog(tmp_path / "f.tlog", _X(tb), C, tb, t_arm=0.5, t_disarm=1.5, pre=0.0)
    for streams, msg in (
            (TLOG_STREAMS.replace('unit = "rad"', 'unit = "deg"'),
             "stream[1].euler.unit: ATTITUDE.roll is in rad (the log says so), mapped as 'deg'"),
            (TLOG_STREAMS.replace('"SCALED_IMU2"', '"SCALED_IMU3"'), "no message 'SCALED_IMU3' (named in"),
            (TLOG_STREAMS.replace('unit = "mG"', 'unit = "m/s^2"'), "SCALED_IMU2.xacc is in mG"),
    ):
        with pytest.raises(logs.LogError, match=msg.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
            _load(_mapping(tmp_path, "bad", "f.tlog", "", streams))
    with pytest.raises(logs.LogError, match="no segment armed in AUTO"):
        _load(_mapping(tmp_path, "auto", "f.tlog", 'modes = ["AUTO"]', TLOG_STREAMS))
    # the autopilot rebooted during the ground station's session: its boot clock starts again
    raw = (tmp_path / "f.tlog").read_bytes()
    (tmp_path / "twice.tlog").write_bytes(raw + raw)
    with pytest.raises(logs.LogError, match=r"message ATTITUDE: the boot clock restarts \(0.000 s after 2.000 s\): "
                                            r"the autopilot rebooted"):
        _load(_mapping(tmp_path, "twice", "twice.tlog", 'segment = "all"', TLOG_STREAMS))


# ---- a .tlog drives the validation on the BlueROV2 Heavy's thrusters ---------------------------------------------

from test_commanded_logs import _commands, _write, rov  # noqa: E402,F401  (the Heavy without its arm)


def test_tlog_drives_validation(rov, tmp_path, capsys):
    """The state the plant computes from a CSV log of PWM commands, written into a .tlog with the same PWM on
    the outputs, read back through the mapping and validated: the reading adds no error beyond MAVLink's float32;
    the same log with two outputs swapped in the mapping does not reproduce the motion."""
    from arvcas.ident import plant, validate

    t, C = _commands(3, 4.0)
    boot = 7.0 + t  # the autopilot has been up 7 s when the trial starts
    csv = logs.load_log(_write(tmp_path, "ref", boot, C), n_joints=0, thruster_names=rov.structure.thrusters)
    X = plant.simulate(plant.LogPlant(rov, m=2), csv, np.zeros(12), rov.params.vector())
    assert np.max(np.abs(X[:, 6:9])) > 0.05 and np.ptp(X[:, 2]) > 0.01  # the thrusters moved the vehicle
    write_tlog(tmp_path / "trial.tlog", X, C, boot, t_arm=boot[0], t_disarm=boot[-1] + 1.0)
    streams = TLOG_STREAMS.replace(PRESSURE, POSITION)
    head = "rate = 50.0\nt_end = 4.0"
    lg = logs.load_log(_mapping(tmp_path, "trial", "trial.tlog", head, streams), n_joints=0,
                       thruster_names=rov.structure.thrusters)
    assert lg.t0 == pytest.approx(7.0) and len(lg.t) == len(t)
    plant.check_commands(lg, rov)
    r = validate.validate_log(rov, lg, h_max=0.01, x0=X[0])
    worst = max(r.metrics["max_error"].values())  # measured: 1.2e-7 rad (yaw), 3e-8 m: MAVLink's float32
    assert worst < 1e-6, r.metrics["max_error"]
    swapped = streams.replace('"T1", "T2"', '"T2", "T1"')
    lg2 = logs.load_log(_mapping(tmp_path, "swapped", "trial.tlog", head, swapped), n_joints=0,
                        thruster_names=rov.structure.thrusters)
    r2 = validate.validate_log(rov, lg2, h_max=0.01, x0=X[0])  # measured: 0.68 m (y), 3.5 rad (yaw)
    assert max(r2.metrics["max_error"].values()) > 100 * max(worst, 1e-6), r2.metrics["max_error"]
    # the command line: the same trial through `arvcas validate`, and a bad mapping refused in one line
    import json

    from arvcas.cli import main

    mapping = tmp_path / "trial.log.toml"
    assert main(["validate", "--system", str(rov.path), str(mapping), "--out", str(tmp_path / "v"), "--h-max",
                 "0.01"]) == 0
    doc = json.loads((tmp_path / "v" / "validation.json").read_text())
    r3 = validate.validate_log(rov, lg, h_max=0.01)  # the initial velocity estimated from the log, as the CLI does
    assert doc["trials"]["trial"]["rmse"] == pytest.approx(r3.metrics["rmse"], rel=1e-9)
    capsys.readouterr()
    bad = _mapping(tmp_path, "bad", "trial.tlog", head, streams.replace('"ATTITUDE"', '"ATTITUDE2"'))
    assert main(["validate", "--system", str(rov.path), str(bad), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no message 'ATTITUDE2'" in err[0] and not (tmp_path / "b").exists(), err


# ---- ROS 1 bags (rosbags reads them as it reads ROS 2 bags) ----------------------------------------------------


def test_ros1_bag(tmp_path):
    pytest.importorskip("rosbags")
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    Imu, Header = ts.types["sensor_msgs/msg/Imu"], ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    Quat, Vec = ts.types["geometry_msgs/msg/Quaternion"], ts.types["geometry_msgs/msg/Vector3"]
    Float = ts.types["std_msgs/msg/Float64"]
    bag = tmp_path / "trial.bag"
    t = np.arange(201) / 100.0
    with Writer(bag) as w:
        ci = w.add_connection("/imu", Imu.__msgtype__, typestore=ts)
        cd = w.add_connection("/depth", Float.__msgtype__, typestore=ts)
        for k, tk in enumerate(t):
            yaw = 0.3 * tk  # about z up (ENU, FLU): NED's yaw is -0.3 t
            stamp = Time(sec=int(100 + tk), nanosec=int(round((100 + tk) % 1 * 1e9)))
            msg = Imu(header=Header(seq=k, stamp=stamp, frame_id="base_link"),
                      orientation=Quat(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
                      orientation_covariance=np.zeros(9), angular_velocity=Vec(x=0.0, y=0.0, z=0.3),
                      angular_velocity_covariance=np.zeros(9), linear_acceleration=Vec(x=0.0, y=0.0, z=9.8),
                      linear_acceleration_covariance=np.zeros(9))
            ns = int(round((100 + tk) * 1e9))
            w.write(ci, ns, ts.serialize_ros1(msg, Imu.__msgtype__))
            w.write(cd, ns, ts.serialize_ros1(Float(data=1.0 + 0.1 * tk), Float.__msgtype__))
    (tmp_path / "r1.log.toml").write_text("""[log]
bag = "trial.bag"
passive = true
rate = 50.0

[[stream]]
topic = "/imu"
time = "header.stamp"
world = "enu"
body = "flu"
quaternion = { columns = ["orientation.x", "orientation.y", "orientation.z", "orientation.w"] }
angular_velocity = { columns = ["angular_velocity.x", "angular_velocity.y", "angular_velocity.z"] }
acceleration = { columns = ["linear_acceleration.x", "linear_acceleration.y", "linear_acceleration.z"] }

[[stream]]
topic = "/depth"
depth = { columns = ["data"], unit = "m" }
""")
    lg = logs.load_log(tmp_path / "r1.log.toml", n_joints=0)
    assert lg.t0 == pytest.approx(100.0) and lg.duration == pytest.approx(2.0)
    # ENU's yaw is from east, counter-clockwise; NED's from north, clockwise: pi/2 - 0.3 t
    assert np.allclose(lg.signals["yaw"], math.pi / 2 - 0.3 * lg.t, atol=1e-9)
    assert np.allclose(lg.signals["r"], -0.3) and np.allclose(lg.signals["z"], 1.0 + 0.1 * lg.t, atol=1e-9)
    (tmp_path / "r2.log.toml").write_text((tmp_path / "r1.log.toml").read_text().replace('"/depth"', '"/dpth"'))
    with pytest.raises(logs.LogError, match="no topic '/dpth'"):
        logs.load_log(tmp_path / "r2.log.toml", n_joints=0)


def test_held_joints_on_the_heavy_with_its_arm(tmp_path):
    """An autopilot's log of the BlueROV2 Heavy + Alpha 5 with the arm stowed: ``[log] held_joints`` holds the
    joints where a joint stream would have to say so. The held log simulates as the same commands with every
    joint logged constant at the stow (the CSV path's joint splines)."""
    import arvcas
    from arvcas.ident import plant, validate

    system = arvcas.load_system("bluerov2_heavy_alpha5")
    stow = [system.params[f"arm.stow.q{k}"] for k in range(1, 5)]
    t, C = _commands(5, 2.0)
    boot = 3.0 + t
    X = _X(boot)
    write_tlog(tmp_path / "arm.tlog", X, C, boot, t_arm=boot[0], t_disarm=boot[-1] + 1.0)
    streams = TLOG_STREAMS.replace(PRESSURE, POSITION)
    held = f"t_end = 2.0\nheld_joints = [{', '.join(map(str, stow))}]"
    lg = logs.load_log(_mapping(tmp_path, "held", "arm.tlog", held, streams), n_joints=4,
                       thruster_names=system.structure.thrusters)
    assert lg.joints.names == ("q1", "q2", "q3", "q4")
    q, qd, qdd = lg.joints(np.array([0.0, 0.7, 2.0]))
    assert np.allclose(q, stow, rtol=0, atol=1e-14) and np.abs(qd).max() < 1e-12 and np.abs(qdd).max() < 1e-12
    np.savetxt(tmp_path / "joints.csv", np.column_stack([boot] + [np.full_like(boot, v) for v in stow]),
               delimiter=",", header="t,a,b,c,d", comments="")
    ref = _write(tmp_path, "ref", boot, C, extra='\n[[stream]]\nfile = "joints.csv"\ntime = "t"\n[stream.joints]\n'
                 + "\n".join(f'q{k} = {{ column = "{c}" }}' for k, c in enumerate("abcd", 1)))
    lg_ref = logs.load_log(ref, n_joints=4, thruster_names=system.structure.thrusters)
    x0 = np.zeros(12)
    x0[2] = 1.0
    r = validate.validate_log(system, lg, h_max=0.01, x0=x0)
    assert r.ok and np.ptp(r.simulated["z"]) > 0.01 and set(r.metrics["rmse"]) >= {"x", "z", "roll", "q4"}
    pl = plant.LogPlant(system, m=2)
    Xa, Xb = (plant.simulate(pl, g, x0, system.params.vector()) for g in (lg, lg_ref))
    assert np.max(np.abs(Xa[:, 6:]) > 0.05) and np.max(np.abs(Xa - Xb)) < 1e-9, np.max(np.abs(Xa - Xb))
    with pytest.raises(logs.LogError, match=r"\[log\] held_joints: 4 angles for a system of 0 joints"):
        logs.load_log(_mapping(tmp_path, "held", "arm.tlog", held, streams), n_joints=0)


# ArduSub's vectored 6DOF frame (BlueROV2 Heavy) as docs/logs.md states it from ArduPilot's
# libraries/AP_Motors/AP_Motors6DOF.cpp @0fd5fbf (the signs of each motor's factors, in words): motor n ->
# (its side forward/aft, starboard/port; the push of a positive output, FRD)
_S = 1 / math.sqrt(2)
ARDUSUB_VECTORED_6DOF = {
    1: ((1, 1), (-_S, _S, 0)), 2: ((1, -1), (-_S, -_S, 0)), 3: ((-1, 1), (_S, _S, 0)), 4: ((-1, -1), (_S, -_S, 0)),
    5: ((1, 1), (0, 0, 1)), 6: ((1, -1), (0, 0, 1)), 7: ((-1, 1), (0, 0, 1)), 8: ((-1, -1), (0, 0, 1)),
}


def test_heavy_thrusters_in_ardusub_motor_order():
    """The shipped Heavy's T_n sits where ArduSub's motor n sits (outputs = ["T1", ..., "T8"]), and its
    direction d_n is the opposite of motor n's push for a positive output (docs/logs.md, Motor order)."""
    import arvcas

    system = arvcas.load_system("bluerov2_heavy_alpha5")
    for n, ((sx, sy), push) in ARDUSUB_VECTORED_6DOF.items():
        pos = [system.params[f"thrusters.T{n}.position.{a}"] for a in "xy"]
        d = np.array([system.params[f"thrusters.T{n}.direction.{a}"] for a in "xyz"])
        assert (np.sign(pos[0]), np.sign(pos[1])) == (sx, sy), n
        assert d @ np.array(push) == pytest.approx(-1.0), n
