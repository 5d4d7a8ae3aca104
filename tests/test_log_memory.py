"""What a log costs in memory is what its mapping keeps, not the file: every reader, on a log where most of
the data is not mapped, stays within twice the float64 size of the values kept plus a constant (peak
resident memory of a fresh process, benchmarks/log_memory.py's logs and measure); and a log whose kept
values would pass ``[log] max_memory_mb`` is refused in one line naming the file, what it would cost and
the setting, before its messages are read where the log has an index (bags, DataFlash)."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

import arvcas
from arvcas.ident import logs, rotations, streams
from arvcas.ident.logs import LogError
from script_helpers import load_script

pytest.importorskip("pymavlink")
pytest.importorskip("rosbags")

log_memory = load_script("benchmarks/log_memory.py")

CODE = Path(arvcas.__file__).resolve().parents[1]
MB = log_memory.MB
# a constant beside the values kept: the readers' blocks (1 MB here), a block's rows or frames as Python
# objects, NumPy's and the readers' temporaries; measured 5-12 MB on 30 MB logs (benchmarks/log_memory.py)
CONSTANT_MB = 16.0


@pytest.mark.slow
@pytest.mark.parametrize("reader", ["csv", "ros1", "ros2-mcap", "ros2-sqlite3", "bin", "tlog"])
def test_a_log_costs_what_it_keeps_not_its_file(tmp_path, reader):
    r = log_memory.measure(reader, tmp_path, 40 * MB, 0.3 * MB, CODE, block=1 << 20)
    assert "error" not in r, r.get("error")
    bound = 2 * r["kept"] + CONSTANT_MB * MB
    assert bound < 0.8 * r["file"]  # the test can fail: a reader that holds the file, or an object per message, does not fit
    assert r["added"] < bound, \
        f"{reader}: {r['added'] / MB:.1f} MB for {r['kept'] / MB:.2f} MB kept of a {r['file'] / MB:.0f} MB log"
    assert r["samples"] > 1000


def _one_line(e, path, what, cap):
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: ") and what in msg, msg
    assert re.search(rf"would keep [\d.,]+ MB of values \(float64\).*more than \[log\] max_memory_mb = {re.escape(f'{cap:g}')} "
                     r"in \S+log.toml: raise it", msg), msg


@pytest.mark.parametrize("reader", ["csv", "ros1", "ros2-mcap", "bin", "tlog"])
def test_a_log_that_would_keep_more_than_max_memory_is_refused(tmp_path, reader, monkeypatch):
    mapping, kept = log_memory.write(reader, tmp_path, 4 * MB)
    cap = float(f"{kept / 2e6:.2g}")  # MB: half what the log keeps
    text = mapping.read_text()
    mapping.write_text(text.replace("[log]\n", f"[log]\nmax_memory_mb = {cap:g}\n", 1))
    where = {"csv": tmp_path / "log.csv", "ros1": tmp_path / "log.bag", "ros2-mcap": tmp_path / "log_bag",
             "bin": tmp_path / "log.bin", "tlog": tmp_path / "log.tlog"}[reader]
    if reader.startswith("ros"):  # from the bag's index: no message is read
        from rosbags.highlevel import AnyReader

        def never(*a, **k):
            raise AssertionError("a message was read")

        monkeypatch.setattr(AnyReader, "deserialize", never)
    with pytest.raises(LogError) as e:
        logs.load_log(mapping)
    what = {"csv": "rows (by row", "ros1": "messages of 8 values", "ros2-mcap": "messages of 8 values",
            "bin": "messages (ATT", "tlog": "values (by ATTITUDE at"}[reader]
    _one_line(e, f"{where}" + (" topic /imu" if reader.startswith("ros") else ""), what, cap)
    # the setting raised far enough, the same log reads
    monkeypatch.undo()
    mapping.write_text(text.replace("[log]\n", f"[log]\nmax_memory_mb = {2 * kept / 1e6 + 1:.1f}\n", 1))
    assert logs.load_log(mapping).t.size > 100


def test_the_budget_is_the_whole_log(tmp_path):
    """Two CSV streams: each under the budget, together over it; the second is refused, naming the first's share."""
    rows = "".join(f"{k * 0.01},{k}\n" for k in range(20_000))
    (tmp_path / "a.csv").write_text("t,x\n" + rows)
    (tmp_path / "b.csv").write_text("t,y\n" + rows)
    (tmp_path / "m.log.toml").write_text('''[log]
passive = true
max_memory_mb = 0.5

[[stream]]
file = "a.csv"
time = "t"
payload = { columns = ["x"] }

[[stream]]
file = "b.csv"
time = "t"
depth = { columns = ["y"], unit = "m" }
''')
    with pytest.raises(LogError, match=rf"^{tmp_path / 'b.csv'}: .* with the streams before it, more than \[log\] "
                                       r"max_memory_mb = 0.5"):
        logs.load_log(tmp_path / "m.log.toml")
    assert streams.Budget("m", 0.5).values == 62_500


@pytest.mark.parametrize("reader", ["bin", "tlog"])
@pytest.mark.parametrize("block", [997, 4096, 65537])
def test_any_block_size_reads_the_same_autopilot_log(tmp_path, reader, block, monkeypatch):
    """The DataFlash and telemetry readers, indexing or scanning blocks of any size (a message cut by every
    block's end), keep the same values as in one block."""
    from arvcas.ident import ardupilot

    mapping, _ = log_memory.write(reader, tmp_path, 0.3 * MB)
    f = tmp_path / f"log.{reader}"
    wanted = {"ATT": {"Roll", "Pitch", "Yaw"}, "IMU": {"I", "GyrX", "GyrY", "GyrZ"}} if reader == "bin" else \
        {"ATTITUDE": {"roll", "pitch", "yaw"}}
    ardupilot._READ.clear()
    whole = ardupilot.read(f, wanted, "m")
    ardupilot._READ.clear()
    monkeypatch.setattr(ardupilot, "DATAFLASH_BLOCK_BYTES" if reader == "bin" else "TLOG_BLOCK_BYTES", block)
    part = ardupilot.read(f, wanted, "m")
    ardupilot._READ.clear()
    assert whole.tables.keys() == part.tables.keys() and len(whole.tables) >= 1
    for k, (t, cols) in whole.tables.items():
        assert t.size >= 100
        np.testing.assert_array_equal(part.tables[k][0], t)
        for c, v in cols.items():
            np.testing.assert_array_equal(part.tables[k][1][c], v)
    assert whole.fields == part.fields and (whole.t_first, whole.t_last) == (part.t_first, part.t_last)


@pytest.mark.slow
def test_an_attitude_log_costs_little_more_than_what_it_keeps(tmp_path):
    """Quaternions alone at the common time base's rate (the Log keeps a sample for every row): the rotation
    matrices, Euler angles and their unwrapping are computed a block at a time, so the peak stays within 3
    times the values read (the CSV reader alone peaks at twice them: its blocks, then one array). Whole-array
    matrices and angles took 9 times (a dozen arrays of every row)."""
    r = log_memory.measure("attitude", tmp_path, 40 * MB, 0.3 * MB, CODE)
    assert "error" not in r, r.get("error")
    assert r["samples"] > 500_000 and r["log"] > 0.75 * r["kept"]
    assert r["added"] < 3 * r["kept"] + CONSTANT_MB * MB, \
        f"{r['added'] / MB:.1f} MB for {r['kept'] / MB:.2f} MB kept ({r['log'] / MB:.1f} MB in the Log)"


def _quaternions(n, rng):
    """Random unit quaternions (x, y, z, w), a third of them within 1e-9..1e-3 rad of gimbal lock (pitch
    +-90 deg), some exactly at it, the first tenth a path whose yaw crosses +-pi (the unwrapping's work)."""
    from scipy.spatial.transform import Rotation

    q = rng.normal(size=(n, 4))
    k = rng.random(n) < 1 / 3
    e = np.stack([rng.uniform(-np.pi, np.pi, n), np.pi / 2 - 10.0 ** rng.uniform(-9, -3, n),
                  rng.uniform(-np.pi, np.pi, n)], axis=1)  # yaw, pitch, roll
    e[::97, 1] = np.pi / 2
    e[1::2, 1] *= -1
    q[k] = Rotation.from_euler("ZYX", e[k]).as_quat()
    q[: n // 10] = Rotation.from_euler("ZYX", np.stack([np.linspace(0, 40, n // 10), 0.1 * np.ones(n // 10),
                                                          0.2 * np.ones(n // 10)], axis=1)).as_quat()
    return q / np.linalg.norm(q, axis=1)[:, None]


@pytest.mark.parametrize("world, body", [("ned", "frd"), ("enu", "flu"), ("nwu", "flu")])
@pytest.mark.parametrize("f, width", [(rotations.R_from_quaternion, 4), (rotations.R_from_euler, 3)])
def test_the_attitude_a_block_at_a_time_is_the_whole_arrays_to_the_bit(world, body, f, width):
    """Euler angles and a point's offset computed a block of rows at a time equal those of every row's matrix
    at once (NumPy's unwrap of the whole array), bit for bit, at any block size."""
    rng = np.random.default_rng(11)
    n = 20_011
    x = _quaternions(n, rng) if width == 4 else \
        np.cumsum(rng.normal(scale=[0.3, 0.2, 1.5], size=(n, 3)), axis=0)
    Cw, Cb = logs.WORLD_FRAMES[world], logs.BODY_FRAMES[body]
    point = np.array([0.3, -0.1, 0.25])
    R = Cw @ f(x) @ Cb
    assert np.ptp(rotations.euler_from_R(R)[:, 2]) > 4 * np.pi  # the unwrapping does work
    for m, blocks in ((1500, (1, 7)), (n, (4096, rotations.BLOCK_ROWS, n + 5))):  # (rows, the block sizes tried)
        whole, arm = rotations.euler_from_R(R[:m]), np.einsum("nij,j->ni", R[:m], point)
        for block in blocks:
            e, a = rotations._attitude(lambda s: x[s], m, f, Cw, Cb, point, block)
            assert np.array_equal(np.stack(e, axis=1), whole), block
            assert np.array_equal(a, arm), block


def test_the_attitude_against_scipy():
    """The angles of random quaternions through a world and a body frame against SciPy's Rotation (ZYX
    intrinsic: yaw, pitch, roll), to 2 pi; near gimbal lock, where roll and yaw are ill-conditioned, the
    rotation the angles make against SciPy's matrix. (Within 1e-7 rad of the lock the angles, read from
    the matrix's entries of order cos(pitch), are not compared: at it roll and yaw are rounding noise.)"""
    from scipy.spatial.transform import Rotation

    q = _quaternions(30_000, np.random.default_rng(5))
    Cw, Cb = logs.WORLD_FRAMES["enu"], logs.BODY_FRAMES["flu"]
    e = np.stack(rotations._attitude(lambda s: q[s], q.shape[0], rotations.R_from_quaternion, Cw, Cb, block=1000)[0], axis=1)
    rot = Rotation.from_matrix(Cw) * Rotation.from_quat(q) * Rotation.from_matrix(Cb)
    R = rot.as_matrix()
    gap = 1 - np.abs(R[:, 2, 0])  # ~ (90 deg - |pitch|)^2 / 2
    far, near = gap > 1e-6, (gap <= 1e-6) & (gap > 1e-14)  # within 1.4e-3 rad of the lock, not within 1.4e-7
    assert far.sum() > 15_000 and near.sum() > 3000
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # SciPy's gimbal-lock warning
        ref = rot[far].as_euler("ZYX")[:, ::-1]
    assert np.max(np.abs(np.angle(np.exp(1j * (e[far] - ref))))) < 1e-9
    np.testing.assert_allclose(rotations.R_from_euler(e[near]), R[near], rtol=0, atol=1e-7)


def test_unwrap_in_place_is_numpys():
    """:func:`arvcas.ident.rotations._unwrap` against ``np.unwrap`` bit for bit, with jumps of exactly +-pi
    (NumPy's boundary rule) and of several turns."""
    rng = np.random.default_rng(2)
    p = np.angle(np.exp(1j * np.cumsum(rng.normal(scale=1.2, size=(5000, 3)), axis=0)))
    p[100:110, 0] = [0, np.pi, 0, -np.pi, 0, np.pi, 2 * np.pi, -np.pi, 0, 3 * np.pi]
    ref = np.unwrap(p, axis=0)
    for block in (1, 3, 4096, 5000):
        for order in ("C", "F"):
            u = np.array(p, order=order)
            assert np.array_equal(rotations._unwrap(u, block), ref), (block, order)


def test_interpolation_a_block_at_a_time_is_numpys():
    """:func:`arvcas.ident.logs._interp`, a block of the time base at a time, equals ``np.interp`` of the whole
    bit for bit: where the time base is denser than the samples (NumPy then computes every slope first),
    sparser, and at the samples' own times."""
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.5, 1.5, 5000))
    y = rng.normal(size=(5000, 3))
    for m in (1000, 20_000):
        tq = np.sort(np.concatenate([np.linspace(t[0], t[-1], m), t[::10]]))
        whole = np.stack([np.interp(tq, t, y[:, i]) for i in range(3)], axis=1)
        for block in (1, 7, 4096, 50_000):
            assert np.array_equal(logs._interp(tq, t, y, block), whole), (m, block)
            assert np.array_equal(logs._interp(tq, t, y[:, 1], block), whole[:, 1]), (m, block)
