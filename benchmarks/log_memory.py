"""What reading a log costs in memory, per reader: peak resident memory against the file's size and the
values the mapping keeps, on synthetic logs where most of the data is not mapped.

    python benchmarks/log_memory.py                       # 50 and 200 MB logs -> results/logs/memory.json
    python benchmarks/log_memory.py --sizes 50 --label before --code /tmp/old   # another checkout's readers

Each log is written to a temporary directory (never committed) with a mapping file, then read by
:func:`arvcas.ident.logs.load_log` in a fresh Python process that reports its peak resident memory
(``VmHWM`` of ``/proc/self/status``: ``ru_maxrss`` would carry the parent's peak across ``exec``) and the
same figure before it, after reading a small log of
the same kind (the baseline: the imports and every first-use cost); ``added`` is their difference. The
logs (seconds of data grow with the size asked):

* ``csv``: a CSV of 24 columns, 4 of them mapped (the time, a position);
* ``ros1``, ``ros2-sqlite3``, ``ros2-mcap``: a bag of an IMU topic at 400 Hz (mapped: quaternion, rates),
  a camera at 5 Hz (100 kB images) and a scalar topic at 5 kHz (neither mapped);
* ``bin``: an ArduSub-like DataFlash log: ATT at 50 Hz and IMU instance 0 at 400 Hz mapped, IMU instance 1,
  raw gyro and accelerometer samples (GYR, ACC) at 4 kHz and BARO not;
* ``tlog``: a MAVLink telemetry log: ATTITUDE at 50 Hz mapped, among 20 times as many other frames;
* ``attitude``: a CSV of quaternions alone (t, x, y, z, w, all mapped) at the common time base's 50 Hz: the
  attitude's conversion (rotation matrices, Euler angles, unwrapping) where the log is nothing else, and the
  Log keeps as many samples as the file has (its t, roll, pitch, yaw: ``log_mb``).

``kept`` is the float64 size of what the mapping keeps (samples x (1 + columns mapped) x 8 bytes).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results" / "logs" / "memory.json"
READERS = ("csv", "ros1", "ros2-sqlite3", "ros2-mcap", "bin", "tlog", "attitude")
MB = 1 << 20
HOW = ("python benchmarks/log_memory.py (--label before --code <checkout of 369b6a1>); added_mb: peak resident memory "
       "(VmHWM) of load_log minus the same after reading a small log of the same kind; kept_mb: float64 size of the "
       "values mapped; log_mb: the Log's arrays (t and the signals); machine shared with other jobs (seconds are not "
       "comparable)")


# ---- CSV ---------------------------------------------------------------------------------------------------

def write_csv(d: Path, size: float) -> tuple[Path, int]:
    """A CSV of ``size`` bytes or so: t, x, y, z mapped, 20 other columns not."""
    n_other = 20
    suffixes = [",".join(f"{v:.5f}" for v in np.random.default_rng(k).normal(size=n_other)) for k in range(997)]
    line0 = f"{0.0:.4f},{1.0:.5f},{2.0:.5f},{3.0:.5f},{suffixes[0]}\n"
    n = int(size / len(line0))
    t = np.arange(n) * 0.001
    with open(d / "log.csv", "w") as f:
        f.write("t,x,y,z," + ",".join(f"c{k}" for k in range(n_other)) + "\n")
        for a in range(0, n, 100_000):
            k = np.arange(a, min(n, a + 100_000))
            f.write("".join(f"{t[i]:.4f},{math.sin(t[i]):.5f},{math.cos(t[i]):.5f},{0.001 * (i % 1000):.5f},"
                            f"{suffixes[i % 997]}\n" for i in k))
    (d / "log.log.toml").write_text('[log]\npassive = true\nmax_gap = 1.0\n\n[[stream]]\nfile = "log.csv"\n'
                                    'time = "t"\nposition = { columns = ["x", "y", "z"], unit = "m" }\n')
    return d / "log.log.toml", n * 4 * 8


# ---- quaternions (CSV) ------------------------------------------------------------------------------------

ATTITUDE_HZ = 50  # the common time base's default rate: the Log keeps a sample for every row


def write_attitude(d: Path, size: float) -> tuple[Path, int]:
    """A CSV of ``size`` bytes or so: t and a unit quaternion (x, y, z, w) a row at :data:`ATTITUDE_HZ`, yaw
    turning through every angle (unwrapped), roll and pitch swinging."""
    line0 = f"{0.0:.2f},{0.0:.7f},{0.0:.7f},{0.0:.7f},{1.0:.7f}\n"
    n = int(size / (len(line0) + 4))
    with open(d / "log.csv", "w") as f:
        f.write("t,qx,qy,qz,qw\n")
        for a in range(0, n, 200_000):
            t = np.arange(a, min(n, a + 200_000)) / ATTITUDE_HZ
            r, p, y = 0.2 * np.sin(0.5 * t) / 2, 0.1 * np.cos(0.3 * t) / 2, 0.3 * t / 2  # half angles, ZYX
            cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
            q = np.stack([t, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
                          cr * cp * cy + sr * sp * sy], axis=1)
            np.savetxt(f, q, fmt="%.2f,%.7f,%.7f,%.7f,%.7f")
    (d / "log.log.toml").write_text(f'[log]\npassive = true\nrate = {ATTITUDE_HZ}\n\n[[stream]]\nfile = "log.csv"\n'
                                    'time = "t"\nquaternion = { columns = ["qx", "qy", "qz", "qw"] }\n')
    return d / "log.log.toml", n * 5 * 8


# ---- ROS bags ----------------------------------------------------------------------------------------------

IMU_HZ, CAMERA_HZ, SCALAR_HZ, IMAGE_BYTES = 400, 5, 5000, 100_000


def _bag_seconds(size: float) -> int:
    per_s = IMU_HZ * 400 + CAMERA_HZ * (IMAGE_BYTES + 300) + SCALAR_HZ * 60  # bytes of a second, roughly
    return max(2, int(size / per_s))


def write_bag(d: Path, size: float, kind: str) -> tuple[Path, int]:
    """A ROS 1 bag (``kind`` "ros1") or a ROS 2 bag ("ros2-sqlite3", "ros2-mcap") of ``size`` bytes or so."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    Imu, Header, Time = T["sensor_msgs/msg/Imu"], T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Quat, Vec, Float, Image = (T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"],
                               T["std_msgs/msg/Float64"], T["sensor_msgs/msg/Image"])
    ser = (lambda m, ty: ts.serialize_ros1(m, ty)) if ros1 else (lambda m, ty: ts.serialize_cdr(m, ty))
    hd = (lambda st: Header(seq=0, stamp=st, frame_id="base_link")) if ros1 else \
        (lambda st: Header(stamp=st, frame_id="base_link"))
    img = ser(Image(header=hd(Time(sec=0, nanosec=0)), height=250, width=400, encoding="mono8", is_bigendian=0,
                    step=400, data=np.zeros(IMAGE_BYTES, np.uint8)), Image.__msgtype__)
    scalar = ser(Float(data=1.0), Float.__msgtype__)
    secs = _bag_seconds(size)
    z9 = np.zeros(9)
    if ros1:
        from rosbags.rosbag1 import Writer

        bag, w = d / "log.bag", None
        writer = Writer(bag)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        bag = d / "log_bag"
        writer = Writer(bag, version=8, storage_plugin=StoragePlugin.SQLITE3 if kind.endswith("sqlite3")
                        else StoragePlugin.MCAP)
    n_imu = 0
    with writer as w:
        kw = {"typestore": ts}
        ci = w.add_connection("/imu", Imu.__msgtype__, **kw)
        cc = w.add_connection("/camera/image_raw", Image.__msgtype__, **kw)
        cs = w.add_connection("/pressure/raw", Float.__msgtype__, **kw)
        for s in range(secs):
            for k in range(SCALAR_HZ):
                tk = s + k / SCALAR_HZ
                ns = int(round((100 + tk) * 1e9))
                if k % (SCALAR_HZ // IMU_HZ) == 0:
                    yaw = 0.3 * tk
                    msg = Imu(header=hd(Time(sec=100 + s, nanosec=int(round(tk % 1 * 1e9)))),
                              orientation=Quat(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
                              orientation_covariance=z9, angular_velocity=Vec(x=0.0, y=0.0, z=0.3),
                              angular_velocity_covariance=z9, linear_acceleration=Vec(x=0.0, y=0.0, z=9.8),
                              linear_acceleration_covariance=z9)
                    w.write(ci, ns, ser(msg, Imu.__msgtype__))
                    n_imu += 1
                if k % (SCALAR_HZ // CAMERA_HZ) == 0:
                    w.write(cc, ns, img)
                w.write(cs, ns, scalar)
    (d / "log.log.toml").write_text(f'''[log]
bag = "{bag.name}"
passive = true

[[stream]]
topic = "/imu"
time = "header.stamp"
world = "enu"
body = "flu"
quaternion = {{ columns = ["orientation.x", "orientation.y", "orientation.z", "orientation.w"] }}
angular_velocity = {{ columns = ["angular_velocity.x", "angular_velocity.y", "angular_velocity.z"] }}
''')
    return d / "log.log.toml", n_imu * 8 * 8


# ---- ArduPilot DataFlash (.bin) ----------------------------------------------------------------------------

# name, id, DataFlash format, columns, rate (Hz), instances
_DF = [("ATT", 130, "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF", 50, (None,)),
       ("IMU", 131, "QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ", 400, (0, 1)),
       ("GYR", 132, "QBQfff", "TimeUS,I,SampleUS,GyrX,GyrY,GyrZ", 4000, (0,)),
       ("ACC", 133, "QBQfff", "TimeUS,I,SampleUS,AccX,AccY,AccZ", 4000, (0,)),
       ("BARO", 134, "QBffcf", "TimeUS,I,Alt,Press,Temp,CRt", 50, (0, 1))]
_DF_NP = {"Q": "<u8", "B": "u1", "f": "<f4", "c": "<i2", "C": "<u2"}


def _fmt_record(mid: int, name: str, fmt: str, cols: str) -> bytes:
    body = struct.pack("<BB4s16s64s", mid, 3 + struct.calcsize("<" + fmt.replace("c", "h").replace("C", "H")),
                       name.encode(), fmt.encode(), cols.encode())
    return bytes([0xA3, 0x95, 128]) + body


def write_dataflash(d: Path, size: float) -> tuple[Path, int]:
    """A DataFlash log of ``size`` bytes or so (the messages of :data:`_DF`, in time order per second)."""
    fmt_fmt = bytes([0xA3, 0x95, 128]) + struct.pack("<BB4s16s64s", 128, 89, b"FMT", b"BBnNZ",
                                                     b"Type,Length,Name,Format,Columns")
    head = fmt_fmt + b"".join(_fmt_record(mid, n, f, c) for n, mid, f, c, _, _ in _DF)
    dts = {n: np.dtype([("h", "u1", 3)] + [(c, _DF_NP[x]) for c, x in zip(cols.split(","), f)])
           for n, _, f, cols, _, _ in _DF}
    per_s = sum(dts[n].itemsize * hz * len(inst) for n, _, _, _, hz, inst in _DF)
    secs = max(2, int(size / per_s))
    n_kept = 0
    with open(d / "log.bin", "wb") as f:
        f.write(head)
        for s in range(secs):
            parts = []
            for n, mid, _, cols, hz, insts in _DF:
                for i in insts:
                    a = np.zeros(hz, dts[n])
                    a["h"] = (0xA3, 0x95, mid)
                    t = s + np.arange(hz) / hz
                    a["TimeUS"] = np.round(t * 1e6).astype(np.uint64) + 7 + (i or 0)
                    if i is not None:
                        a["I"] = i
                    if n == "ATT":
                        a["Roll"], a["Pitch"] = np.round(1000 * np.sin(0.5 * t)), np.round(-500 * np.cos(0.3 * t))
                        a["Yaw"] = np.round(100 * ((30 + 20 * t) % 360))
                        n_kept += hz * 4
                    elif n == "IMU":
                        a["GyrX"], a["GyrZ"], a["AccZ"] = 0.01, 0.03, -9.8
                        n_kept += hz * 4 if i == 0 else 0
                    elif n == "BARO":
                        a["Press"] = 101325.0 + 10000.0 * (i or 0)
                    parts.append((t, a.tobytes(), dts[n].itemsize))
            # interleave by time: one record at a time is too slow to write, so whole blocks of 10 ms
            blocks = []
            for t, raw, sz in parts:
                k = np.floor(t * 100 + 1e-9).astype(int) - s * 100
                edges = np.searchsorted(k, np.arange(101))
                blocks.append([raw[edges[j] * sz:edges[j + 1] * sz] for j in range(100)])
            f.write(b"".join(b[j] for j in range(100) for b in blocks))
    (d / "log.log.toml").write_text('''[log]
ardupilot = "log.bin"
segment = "all"
passive = true

[[stream]]
message = "ATT"
euler = { columns = ["Roll", "Pitch", "Yaw"], unit = "deg" }

[[stream]]
message = "IMU"
instance = 0
angular_velocity = { columns = ["GyrX", "GyrY", "GyrZ"], unit = "rad/s" }
''')
    return d / "log.log.toml", n_kept * 8


# ---- ArduPilot telemetry (.tlog) ---------------------------------------------------------------------------

TLOG_HZ, TLOG_OTHER = 50, 20  # ATTITUDE's rate; frames of other messages per ATTITUDE frame


def write_tlog(d: Path, size: float) -> tuple[Path, int]:
    """A telemetry log of ``size`` bytes or so: a heartbeat a second, ATTITUDE at :data:`TLOG_HZ`, and after
    each ATTITUDE :data:`TLOG_OTHER` frames of other messages (a pool packed once, written again and again)."""
    from pymavlink.dialects.v20 import ardupilotmega as mav

    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    stamp = struct.pack(">Q", int(1.7e15))
    other = [stamp + mav.MAVLink_scaled_imu2_message(k, 1, 2, -1000, 0, 0, 0, 0, 0, 0).pack(m) for k in range(7)] + \
        [stamp + mav.MAVLink_servo_output_raw_message(k, 0, *[1500] * 8).pack(m) for k in range(7)] + \
        [stamp + mav.MAVLink_vfr_hud_message(0.1, 0.1, 90, 0, 1.0, 0.0).pack(m) for _ in range(6)]
    block = b"".join(other[:TLOG_OTHER])
    att_size = len(stamp + mav.MAVLink_attitude_message(0, 0, 0, 0, 0, 0, 0).pack(m))
    n = max(100, int(size / (len(block) + att_size)))
    with open(d / "log.tlog", "wb") as f:
        for k in range(n):
            t = k / TLOG_HZ
            if k % TLOG_HZ == 0:
                f.write(stamp + mav.MAVLink_heartbeat_message(mav.MAV_TYPE_SUBMARINE, mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                              0, 19, 4, 3).pack(m))
            f.write(stamp + mav.MAVLink_attitude_message(int(round(t * 1000)), 0.1 * math.sin(0.5 * t), 0.0,
                                                         (0.3 * t) % 6.0 - 3.0, 0.0, 0.0, 0.3).pack(m))
            f.write(block)
    (d / "log.log.toml").write_text('''[log]
ardupilot = "log.tlog"
segment = "all"
passive = true

[[stream]]
message = "ATTITUDE"
euler = { columns = ["roll", "pitch", "yaw"], unit = "rad" }
''')
    return d / "log.log.toml", n * 4 * 8


def write(reader: str, d: Path, size: float) -> tuple[Path, int]:
    """A log for ``reader`` (one of :data:`READERS`) of ``size`` bytes or so in ``d``: (its mapping, kept bytes)."""
    if reader == "csv":
        return write_csv(d, size)
    if reader.startswith("ros"):
        return write_bag(d, size, reader)
    if reader == "bin":
        return write_dataflash(d, size)
    if reader == "tlog":
        return write_tlog(d, size)
    if reader == "attitude":
        return write_attitude(d, size)
    raise ValueError(f"reader {reader!r}: one of {', '.join(READERS)}")


_CHILD = """
import json, resource, sys, time


def hwm():  # KiB: this process's peak resident memory (Linux: VmHWM, which a fork does not inherit)
    try:
        with open("/proc/self/status") as f:
            return int(next(ln for ln in f if ln.startswith("VmHWM:")).split()[1])
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


from arvcas.ident import logs
from arvcas.ident import ardupilot, streams
if len(sys.argv) > 3:  # the readers' block size (bytes)
    streams.CSV_BLOCK_BYTES = ardupilot.TLOG_BLOCK_BYTES = ardupilot.DATAFLASH_BLOCK_BYTES = int(sys.argv[3])
logs.load_log(sys.argv[2])  # a small log of the same kind first: every import and first-use cost
base = hwm()
t0 = time.perf_counter()
lg = logs.load_log(sys.argv[1])
dt = time.perf_counter() - t0
peak = hwm()
print(json.dumps({"base_kib": base, "peak_kib": peak, "seconds": dt, "samples": int(lg.t.size),
                  "log_bytes": 8 * (lg.t.size + sum(v.size for v in lg.signals.values()))}))
"""


def peak(mapping: Path, small: Path, code: Path = ROOT, block: int | None = None) -> dict:
    """Peak resident memory (KiB) of a fresh process that reads ``mapping`` with the readers of ``code``, and
    the same figure before it (``base_kib``: after reading ``small``, a small log of the same kind); ``block``:
    the bytes the CSV, telemetry and DataFlash readers read at a time (default theirs)."""
    env = dict(os.environ, PYTHONPATH=str(code))
    r = subprocess.run([sys.executable, "-c", _CHILD, str(mapping), str(small)] + ([str(block)] if block else []),
                       env=env, capture_output=True, text=True, cwd=code)  # (python -c puts the cwd first on sys.path)
    if r.returncode:
        raise RuntimeError(f"{mapping}: {r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def log_size(mapping: Path) -> int:
    d = mapping.parent
    return sum(p.stat().st_size for p in d.rglob("*") if p.is_file() and p != mapping)


def measure(reader: str, d: Path, size: float, small: float = 0.5 * MB, code: Path = ROOT,
            block: int | None = None) -> dict:
    """Write a log for ``reader`` of ``size`` bytes in ``d`` (and one of ``small`` bytes: the baseline) and
    read it in a fresh process (:func:`peak`): its row of the results, in bytes (``file``, ``kept``: the
    float64 values mapped, ``log``: the Log's arrays, ``added``: peak resident memory minus the baseline's),
    and ``error`` where the read failed."""
    (d / "big").mkdir()
    (d / "small").mkdir()
    mapping, kept = write(reader, d / "big", size)
    small_mapping, _ = write(reader, d / "small", small)
    row = {"file": log_size(mapping), "kept": kept}
    try:
        r = peak(mapping, small_mapping, code, block)
    except RuntimeError as e:
        return {**row, "error": str(e)}
    return {**row, "base": r["base_kib"] * 1024, "peak": r["peak_kib"] * 1024,
            "added": (r["peak_kib"] - r["base_kib"]) * 1024, "log": r["log_bytes"], "seconds": r["seconds"],
            "samples": r["samples"]}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=float, nargs="+", default=[50, 200], help="log sizes, MB")
    ap.add_argument("--readers", nargs="+", default=list(READERS), choices=READERS)
    ap.add_argument("--label", default="after", help="the key the figures are stored under")
    ap.add_argument("--code", type=Path, default=ROOT, help="the checkout whose arvcas reads the logs")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--note", help="what the code measured is, stored with the label")
    a = ap.parse_args(argv)
    out = json.loads(a.out.read_text()) if a.out.is_file() else {}
    rows = out.setdefault(a.label, {})
    commit = subprocess.run(["git", "-C", str(a.code), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip() or None
    for reader in a.readers:
        for size in a.sizes:
            with tempfile.TemporaryDirectory(prefix="arvcas-logmem-") as tmp:
                r = measure(reader, Path(tmp), size * MB, code=a.code)
                row = {"file_mb": round(r["file"] / MB, 1), "kept_mb": round(r["kept"] / MB, 2)}
                if "error" in r:
                    row["error"] = r["error"]
                else:
                    row.update(base_mb=round(r["base"] / MB, 1), peak_mb=round(r["peak"] / MB, 1),
                               added_mb=round(r["added"] / MB, 1), log_mb=round(r["log"] / MB, 2),
                               seconds=round(r["seconds"], 2))
                rows[f"{reader} {size:g}MB"] = row
                print(f"{reader:13s} {size:5g} MB: {row}", flush=True)
    about = out.setdefault("about", {})
    about["how"] = HOW
    about[a.label] = {"code": commit, "python": sys.version.split()[0], **({"note": a.note} if a.note else {})}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
