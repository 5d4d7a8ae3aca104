"""A log's stream read as a table (:class:`Table`: its time column and the columns named): a CSV file
(``.gz``: gzip), streamed in blocks, or a ROS bag's topic (:mod:`rosbags`). Both are bounded (bytes, rows,
values kept) and every fault is one :class:`LogError` line naming the file, the row or field and the
reason. :mod:`arvcas.ident.logs` turns the tables into a :class:`~arvcas.ident.logs.Log`.
"""

from __future__ import annotations

import gzip
import io
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from arvcas.system import config

__all__ = ["LogError", "Table", "Budget", "read_csv", "read_bag", "MAX_LOG_BYTES", "MAX_SAMPLES", "CSV_BLOCK_BYTES",
           "MAX_MEMORY_MB"]

MAX_LOG_BYTES = 1 << 30  # one stream file (after decompression); a trial of an hour at 1 kHz is ~100 MB
MAX_SAMPLES = 20_000_000  # rows of one stream
# MB (10^6 bytes) the values a log keeps may take as float64: [log] max_memory_mb's default (100 million values)
MAX_MEMORY_MB = 800.0


class LogError(ValueError):
    """One line naming the mapping or stream file, the key or column, and the reason."""


@dataclass
class Budget:
    """What one log may keep: ``max_mb`` MB of float64 values (``[log] max_memory_mb`` of ``mapping``), spent
    stream by stream. A reader asks :meth:`check` before it keeps values: from an index (a bag's message
    counts, a DataFlash log's) before reading them, or as it reads (a CSV file, a telemetry log)."""

    mapping: str
    max_mb: float = MAX_MEMORY_MB
    used: int = 0  # values kept by the streams read so far

    @property
    def values(self) -> int:
        """The values the whole log may keep."""
        return int(self.max_mb * 1e6 // 8)

    def check(self, values: int, where: str, what: str) -> None:
        """:class:`LogError` if ``values`` more than those kept would pass the budget: one line naming
        ``where`` (the file), ``what`` it would keep, what that costs and the setting."""
        if self.used + values > self.values:
            mb = (self.used + values) * 8 / 1e6
            raise LogError(f"{where}: {what} would keep {f'{mb:,.0f}' if mb >= 10 else f'{mb:.2g}'} MB of values "
                           f"(float64) with the streams before it, more than [log] max_memory_mb = {self.max_mb:g} "
                           f"in {self.mapping}: raise it, cut the log, or map fewer fields")

    def spend(self, values: int, where: str, what: str) -> None:
        self.check(values, where, what)
        self.used += values

@dataclass
class Table:
    where: str  # the file (and topic) for messages
    time: np.ndarray
    time_name: str
    cols: dict[str, np.ndarray]


def read_csv(path: Path, names: list[str], time_col: str, mapping: str, budget: Budget | None = None) -> Table:
    """The columns ``names`` (and the time) of a CSV log (``.gz``: gzip), streamed in blocks of whole lines
    (:data:`CSV_BLOCK_BYTES`): what it costs is the columns read, not the file. Every row must have as many
    fields as the header (a decimal comma shifts every column: refused naming the row); a corrupt gzip
    file, more than :data:`MAX_LOG_BYTES` of text, :data:`MAX_SAMPLES` rows or more values than ``budget``
    (default: :data:`MAX_MEMORY_MB`) are one line, as soon as a block passes them."""
    budget = budget or Budget(mapping)
    import zlib

    from arvcas.util.files import check_input

    check_input(path, "log file", LogError)
    gz = path.suffix == ".gz"
    if not gz and path.stat().st_size > MAX_LOG_BYTES:
        raise LogError(f"{path}: more than {MAX_LOG_BYTES} bytes (arvcas.ident.streams.MAX_LOG_BYTES)")
    try:
        f = gzip.open(path, "rb") if gz else open(path, "rb")
    except OSError as e:
        raise LogError(f"{path}: cannot be read ({e.strerror or e})") from None
    blocks, n_rows, line, total = [], 0, 2, 0  # line: the file line the next block starts at (the header: 1)
    try:
        with f:
            head = f.readline(1 << 20)
            header = [h.strip().strip('"') for h in _utf8(head, path, 1).lstrip("\ufeff").strip().split(",")]
            if len(set(header)) != len(header):
                dup = next(h for h in header if header.count(h) > 1)
                raise LogError(f"{path}: header names column {dup!r} twice")
            want = [time_col] + [n for n in names if n != time_col]
            for n in want:
                if n not in header:
                    raise LogError(f"{path}: no column {n!r} (named in {mapping}){config.closest(n, header)}")
            idx = [header.index(n) for n in want]
            rest = b""
            while True:
                chunk = f.read(CSV_BLOCK_BYTES)
                total += len(chunk)
                if total > MAX_LOG_BYTES:
                    raise LogError(f"{path}: more than {MAX_LOG_BYTES} bytes{' once decompressed' if gz else ''} "
                                   f"(arvcas.ident.streams.MAX_LOG_BYTES)")
                data = rest + chunk
                if chunk:
                    cut = data.rfind(b"\n") + 1
                    data, rest = data[:cut], data[cut:]
                if data:
                    block, n_lines = _csv_block(data, path, line, len(header), idx)
                    line += n_lines
                    n_rows += block.shape[0]
                    if n_rows > MAX_SAMPLES:
                        raise LogError(f"{path}: more than {MAX_SAMPLES} rows (arvcas.ident.streams.MAX_SAMPLES)")
                    budget.check(n_rows * len(want), str(path), f"{n_rows:,} rows (by row {line - 1}) of the "
                                                                f"{len(want)} columns read")
                    blocks.append(block)
                if not chunk:
                    break
    except (EOFError, zlib.error, gzip.BadGzipFile) as e:
        raise LogError(f"{path}: not a readable gzip file ({' '.join(str(e).split()) or type(e).__name__})") from None
    except OSError as e:
        raise LogError(f"{path}: {'not a readable gzip file' if gz else 'cannot be read'} "
                       f"({' '.join(str(e).split())})") from None
    data = np.concatenate(blocks) if blocks else np.zeros((0, len(want)))
    del blocks
    if data.shape[0] < 2:
        raise LogError(f"{path}: fewer than 2 rows of data")
    budget.spend(data.size, str(path), f"its {len(want)} columns read")
    cols = {n: data[:, i] for i, n in enumerate(want)}
    return Table(str(path), cols.pop(time_col), time_col, cols)


CSV_BLOCK_BYTES = 8 << 20  # a CSV log is read this much at a time


def _utf8(raw: bytes, path: Path, line: int) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise LogError(f"{path}: not UTF-8 text (row {line}, byte {e.start})") from None


def _csv_block(data: bytes, path: Path, line: int, width: int, idx: list[int]) -> tuple[np.ndarray, int]:
    """The columns ``idx`` of whole CSV lines ``data`` (file line ``line`` first); every line that is not blank
    or a comment has ``width`` fields. Returns (rows, lines read)."""
    lines = data.split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    for k, ln in enumerate(lines):
        n = ln.count(b",") + 1
        if n != width and ln.strip() and not ln.lstrip().startswith(b"#"):
            why = " (a decimal comma? fields are separated by commas and decimals take a point)" if n > width else ""
            raise LogError(f"{path}: row {line + k}: {n} fields, the header has {width}{why}")
    try:
        _utf8(data, path, line)  # (a str of the block would cost 1-4 bytes a character: NumPy reads the bytes)
        with warnings.catch_warnings():  # a block of only blank or comment lines holds no data: no warning
            warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
            rows = np.loadtxt(io.BytesIO(data), delimiter=",", usecols=idx, ndmin=2, dtype=float, encoding="utf-8")
    except ValueError as e:
        msg = " ".join(str(e).split())
        raise LogError(f"{path}: a number could not be read in rows {line} to {line + len(lines) - 1} "
                       f"({msg[:160]})") from None
    return rows.reshape(-1, len(idx)), len(lines)


def _field(msg: Any, path: str) -> float:
    v = msg
    for part in path.split("."):
        m = re.fullmatch(r"([A-Za-z_]\w*)(?:\[(\d+)\])?", part)
        if m is None or not hasattr(v, m.group(1)):
            raise KeyError(path)
        v = getattr(v, m.group(1))
        if m.group(2) is not None:
            v = v[int(m.group(2))]
    if hasattr(v, "sec") and hasattr(v, "nanosec"):  # builtin_interfaces/Time
        return float(v.sec) + 1e-9 * float(v.nanosec)
    return float(v)


def _ros1_reader(bag: Path, topic: str):
    """rosbags' ROS 1 reader of ``bag`` that indexes the messages of ``topic`` only: rosbags reads the index of
    every chunk when it opens a bag, an object of ~100 bytes a message of any topic; the other topics' are
    dropped chunk by chunk (their message count reads 0)."""
    from rosbags.rosbag1 import Reader

    class _Sink(dict):
        def __init__(self, indexes, keep):
            super().__init__()
            self.indexes, self.keep = indexes, keep

        def __getitem__(self, conn):
            return self.indexes[conn] if conn in self.keep else []

    class TopicReader(Reader):
        def read_index_data(self, pos, indexes):
            keep = {c.id for c in self.connections if c.topic == topic}
            super().read_index_data(pos, _Sink(indexes, keep))

    return TopicReader(bag)


def read_bag(bag: Path, topic: str, names: list[str], time_field: str | None, mapping: str,
             budget: Budget | None = None) -> Table:
    """The fields ``names`` (and the time) of the messages of one topic of a ROS bag. Only that topic's
    messages are read and deserialised, one at a time, into float64 arrays sized by the bag's message count
    (its index or metadata), which is checked against ``budget`` (default: :data:`MAX_MEMORY_MB`) and
    :data:`MAX_SAMPLES` before any message is read."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise LogError(f"{mapping}: reading ROS bags needs the rosbags package: pip install 'arvcas[bags]'") \
            from None
    budget = budget or Budget(mapping)
    where = f"{bag} topic {topic}"
    n = 0
    try:
        reader = AnyReader([bag])
        if not reader.is2:  # a ROS 1 bag: its index of the other topics' messages is not kept
            reader.readers = [_ros1_reader(bag, topic)]
        with reader:
            conns = [c for c in reader.connections if c.topic == topic]
            if not conns:
                topics = sorted({c.topic for c in reader.connections})
                raise LogError(f"{bag}: no topic {topic!r} (named in {mapping}){config.closest(topic, topics)}")
            count = sum(int(c.msgcount or 0) for c in conns)
            if count > MAX_SAMPLES:
                raise LogError(f"{where}: {count:,} messages, more than {MAX_SAMPLES:,} "
                               f"(arvcas.ident.streams.MAX_SAMPLES)")
            budget.check(count * (1 + len(names)), where, f"{count:,} messages of {1 + len(names)} values")
            data = np.empty((max(count, 2), 1 + len(names)))  # the time, then the fields
            for conn, stamp, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                if n == data.shape[0]:  # more messages than the index counted
                    if n >= MAX_SAMPLES:
                        raise LogError(f"{where}: more than {MAX_SAMPLES:,} messages (arvcas.ident.streams.MAX_SAMPLES)")
                    budget.check(2 * n * data.shape[1], where, f"more than {n:,} messages of {data.shape[1]} values")
                    data = np.concatenate([data, np.empty_like(data)])
                try:
                    data[n, 0] = stamp * 1e-9 if time_field is None else _field(msg, time_field)
                    data[n, 1:] = [_field(msg, nm) for nm in names]
                except KeyError as e:
                    raise LogError(f"{where}: message {conn.msgtype} has no field {e.args[0]!r}") from None
                except (TypeError, ValueError, IndexError):
                    raise LogError(f"{where}: a field of {names} is not a number") from None
                n += 1
    except LogError:
        raise
    except Exception as e:  # rosbags' own errors: unreadable metadata, storage, message types
        raise LogError(f"{bag}: not a readable ROS bag ({type(e).__name__}: {' '.join(str(e).split())[:160]})") \
            from None
    if n < 2:
        raise LogError(f"{where}: fewer than 2 messages")
    data = data[:n]
    budget.spend(data.size, where, f"{n:,} messages of {data.shape[1]} values")
    return Table(where, data[:, 0], time_field or "log time", {nm: data[:, i + 1] for i, nm in enumerate(names)})
