"""What a log costs in memory is what its mapping keeps, not the file: every reader, on a log where most of
the data is not mapped, stays within twice the float64 size of the values kept plus a constant (peak
resident memory of a fresh process, benchmarks/log_memory.py's logs and measure); and a log whose kept
values would pass ``[log] max_memory_mb`` is refused in one line naming the file, what it would cost and
the setting, before its messages are read where the log has an index (bags, DataFlash)."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest

import arvcas
from arvcas.ident import logs, streams
from arvcas.ident.logs import LogError

pytest.importorskip("pymavlink")
pytest.importorskip("rosbags")

_spec = importlib.util.spec_from_file_location(
    "log_memory", Path(__file__).resolve().parents[1] / "benchmarks" / "log_memory.py")
log_memory = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(log_memory)

CODE = Path(arvcas.__file__).resolve().parents[1]
MB = log_memory.MB
# a constant beside the values kept: the readers' blocks (1 MB here), a block's rows or frames as Python
# objects, NumPy's and the readers' temporaries; measured 5-12 MB on 30 MB logs (benchmarks/log_memory.py)
CONSTANT_MB = 16.0


@pytest.mark.slow
@pytest.mark.parametrize("reader", ["csv", "ros1", "ros2-mcap", "ros2-sqlite3", "bin", "tlog"])
def test_a_log_costs_what_it_keeps_not_its_file(tmp_path, reader):
    (tmp_path / "big").mkdir()
    (tmp_path / "small").mkdir()
    mapping, kept = log_memory.write(reader, tmp_path / "big", 40 * MB)
    small, _ = log_memory.write(reader, tmp_path / "small", 0.3 * MB)
    size = log_memory.log_size(mapping)
    r = log_memory.peak(mapping, small, CODE, block=1 << 20)
    added = (r["peak_kib"] - r["base_kib"]) * 1024
    bound = 2 * kept + CONSTANT_MB * MB
    assert bound < 0.8 * size  # the test can fail: a reader that holds the file, or an object per message, does not fit
    assert added < bound, f"{reader}: {added / MB:.1f} MB for {kept / MB:.2f} MB kept of a {size / MB:.0f} MB log"
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


@pytest.mark.parametrize("f, width", [(logs.R_from_euler, 3), (logs.R_from_quaternion, 4)])
def test_rotations_a_block_at_a_time_are_the_same_to_the_bit(f, width):
    """The attitude's matrices built a block of rows at a time equal those built at once (every row is
    computed alone: elementwise trigonometry and a 3 x 3 product)."""
    x = np.random.default_rng(3).normal(size=(100_003, width))
    if width == 4:
        x /= np.linalg.norm(x, axis=1)[:, None]
    Cw, Cb = logs.WORLD_FRAMES["enu"], logs.BODY_FRAMES["flu"]
    whole = Cw @ f(x) @ Cb
    for block in (1, 7, 4096, 1 << 16):
        assert np.array_equal(logs._rotations(f, x, Cw, Cb, block), whole), block
