"""ArduPilot's own logs: DataFlash ``.bin`` files (the autopilot's SD card) and MAVLink telemetry ``.tlog``
files (QGroundControl's, MAVProxy's), read through pymavlink (``pip install 'arvcas[ardupilot]'``).

:func:`read` makes one pass over the file and keeps, for every message the mapping names, its times on the
autopilot's boot clock (s) and the named fields; besides them the arming and flight-mode changes and the
parameters. :func:`segments` cuts the log into the stretches the vehicle was armed (and in given modes).

Time base: the autopilot's boot clock, never the ground station's wall clock: ``TimeUS`` in a DataFlash
log; ``time_boot_ms`` in a telemetry log, else ``time_usec`` (which ArduPilot fills with its boot clock
too; a value beyond 30 years is a Unix time and is refused; a 32-bit ``time_usec`` such as
``SERVO_OUTPUT_RAW``'s is unwrapped after 71.6 min). A telemetry log keeps the messages of one vehicle: the
system id whose ``HEARTBEAT`` names an ArduPilot autopilot; a message that repeats its predecessor's boot
time is a repeated transmission and is dropped.

Arming and modes: a DataFlash log's ``ARM`` messages (``ArmState``) or, in older logs, its ``EV`` events 10
(armed) and 11 (disarmed), and its ``MODE`` messages (``Mode``, ArduSub's mode number); a telemetry log's
``HEARTBEAT`` (``base_mode``'s safety-armed flag, ``custom_mode``), placed on the boot clock at the latest
message of the same vehicle that carries ``time_boot_ms`` (heartbeats come at 1 Hz: a cut is known to that
period). Mode names are pymavlink's for ArduSub (``mavutil.mode_mapping_sub``); a mode it does not name is
``MODE<n>``.
"""

from __future__ import annotations

import math
import re
from array import array
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from arvcas.ident.streams import Budget, LogError

__all__ = ["AutopilotLog", "Segment", "Error", "read", "table", "segments", "mode_name", "KINDS", "BOOT_TIME_FIELDS",
           "LOG_UNITS"]

KINDS = {".bin": "DataFlash", ".tlog": "MAVLink telemetry"}
# the boot-clock fields, in the order a stream's default time is chosen, and their counts per second
BOOT_TIME_FIELDS = {"TimeUS": 1e6, "time_boot_ms": 1e3, "time_usec": 1e6}
_UNIX_TIME_S = 30 * 365.25 * 86400  # a "boot time" beyond 30 years is a Unix time (the wall clock)
_EV_ARMED, _EV_DISARMED = 10, 11  # DataFlash EV ids (ArduPilot AP_Logger's enum LogEvent: ARMED, DISARMED)
_ARMED_FLAG = 128  # MAV_MODE_FLAG_SAFETY_ARMED in HEARTBEAT.base_mode
_AUTOPILOT_ARDUPILOT = 3  # MAV_AUTOPILOT_ARDUPILOTMEGA
# the log's own unit labels (MAVLink XML units, DataFlash UNIT labels) -> arvcas units (arvcas.system.config)
LOG_UNITS = {"rad": "rad", "deg": "deg", "degheading": "deg", "rad/s": "rad/s", "deg/s": "deg/s", "mrad/s": "mrad/s",
             "m": "m", "cm": "cm", "mm": "mm", "m/s": "m/s", "cm/s": "cm/s", "mm/s": "mm/s", "m/s/s": "m/s^2",
             "m/s2": "m/s^2", "mG": "mG", "Pa": "Pa", "hPa": "hPa", "us": "us", "PWM": "us"}


_NUMPY = {"b": "i1", "B": "u1", "h": "i2", "H": "u2", "i": "i4", "I": "u4", "q": "i8", "Q": "u8", "f": "f4", "d": "f8",
          "e": "f2"}  # struct codes of DataFlash formats -> NumPy


class Error(ValueError):
    """One line: the log file, the message or field, the reason (arvcas.ident.logs turns it into LogError)."""


@dataclass
class AutopilotLog:
    path: Path
    kind: str  # "DataFlash" | "MAVLink telemetry"
    tables: dict = field(default_factory=dict)  # (message, instance) -> (t (s, boot clock), {field: values})
    fields: dict = field(default_factory=dict)  # message -> its field names (every message the log holds)
    units: dict = field(default_factory=dict)  # message -> {field: the log's unit label}
    instances: dict = field(default_factory=dict)  # message -> the instance numbers present (DataFlash)
    params: dict = field(default_factory=dict)  # parameter name -> value (the last one logged)
    changes: list = field(default_factory=list)  # (t, armed, mode number) at every change, in time order
    t_first: float = math.inf
    t_last: float = -math.inf
    arming_logged: bool = False


@dataclass(frozen=True)
class Segment:
    start: float  # s, boot clock
    end: float
    modes: tuple[str, ...]

    def __str__(self) -> str:
        return f"{self.start:.3f}-{self.end:.3f} s ({', '.join(self.modes)})"


def mode_name(number: int | None) -> str:
    from pymavlink import mavutil

    if number is None:
        return "unknown"
    return mavutil.mode_mapping_sub.get(int(number), f"MODE{int(number)}")


def _import(mapping: str):
    try:
        from pymavlink import mavutil
    except ImportError:
        raise Error(f"{mapping}: reading ArduPilot logs needs the pymavlink package: pip install 'arvcas[ardupilot]'") \
            from None
    return mavutil


def read(path: Path, wanted: dict[str, set[str]], mapping: str, budget: Budget | None = None) -> AutopilotLog:
    """The messages ``wanted`` (message -> field names) of the log ``path``, with arming, modes and parameters.

    Unknown messages and fields are refused (one line listing what the log holds) after the pass. What the
    messages keep (their times and fields, float64) is checked against ``budget`` (default:
    :data:`arvcas.ident.streams.MAX_MEMORY_MB`): from the index of a DataFlash log before any message is
    unpacked, as it is read in a telemetry log (:class:`arvcas.ident.streams.LogError`)."""
    mavutil = _import(mapping)
    budget = budget or Budget(mapping)
    kind = KINDS.get(path.suffix.lower())
    if kind is None:
        raise Error(f"{path}: not an ArduPilot log: the file name ends in .bin (DataFlash) or .tlog (MAVLink "
                    f"telemetry), got {path.suffix or 'no suffix'!r}")
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size,
           tuple(sorted((k, tuple(sorted(v))) for k, v in wanted.items())))
    if key in _READ:  # several mappings (a dive's segments) on one log: read once per process
        out = _READ[key]
    else:
        out = _READ[key] = _read(mavutil, path, kind, wanted, budget)
        while len(_READ) > _READ_KEPT:
            _READ.pop(next(iter(_READ)))
    budget.spend(sum(t.size * (1 + len(c)) for t, c in out.tables.values()), str(path), "the messages named")
    for msg, names in wanted.items():
        if msg not in out.fields:
            raise Error(f"{path}: no message {msg!r} (named in {mapping}); the log holds "
                        f"{', '.join(sorted(out.fields)) or 'none'}")
        missing = [n for n in sorted(names) if _base(n) not in out.fields[msg]]
        if missing:
            raise Error(f"{path}: message {msg} has no field {missing[0]!r} (named in {mapping}); its fields: "
                        f"{', '.join(out.fields[msg])}")
    return out


_READ: dict = {}  # (file, its mtime and size, the messages and fields read) -> AutopilotLog
_READ_KEPT = 8


def _read(mavutil, path: Path, kind: str, wanted: dict[str, set[str]], budget: Budget) -> AutopilotLog:
    try:
        if kind == "DataFlash":
            out = _read_dataflash(mavutil, path, wanted, budget)
        else:
            out = _read_tlog(mavutil, path, wanted, budget)
    except (Error, LogError):
        raise
    except Exception as e:  # pymavlink's own errors on a damaged file
        raise Error(f"{path}: not a readable {kind} log ({type(e).__name__}: {' '.join(str(e).split())[:160]})") \
            from None
    return out


def _give_back(data_map, start: int, end: int) -> None:
    """Drop the pages of bytes ``start:end`` of a mapped file from this process's memory (they are read
    from the file again if touched): what reading a log costs is then what it keeps, not the file."""
    import mmap

    if hasattr(data_map, "madvise") and hasattr(mmap, "MADV_DONTNEED"):
        lo = start // mmap.PAGESIZE * mmap.PAGESIZE
        data_map.madvise(mmap.MADV_DONTNEED, lo, min(end, len(data_map)) - lo)


def _index_blocks(r, keep: set[str]) -> tuple[list, list[int]]:
    """The offsets of the messages of a DataFlash log (``r``, pymavlink's reader: its mapped file) that ``keep``
    names (NumPy arrays, by message type), and every type's count: pymavlink's indexer run on blocks of
    :data:`DATAFLASH_BLOCK_BYTES`, each after the FMT messages seen before it (a message's length is its
    format's); the indexer stops where pymavlink's stops (a message of no format). Each block's pages are
    given back to the system after it is indexed."""
    from pymavlink import dfindexer

    fmt_len = r.formats[0x80].len
    lengths = {0x80: fmt_len}
    names: dict[int, str] = {0x80: "FMT"}
    kept: dict[int, list] = {}
    counts = [0] * 256
    prefix = b""  # every FMT message so far
    pos, n = 0, r.data_len
    while pos < n:
        end = min(pos + DATAFLASH_BLOCK_BYTES, n)
        buf = prefix + r.data_map[pos:end]
        base = pos - len(prefix)
        found = dfindexer.build_offsets(memoryview(buf), 0x80, fmt_len, 3, 4, r.HEAD1, r.HEAD2)
        last = pos
        for t in [0x80] + [t for t in range(256) if t != 0x80]:
            if not found[t]:
                continue
            a = np.asarray(found[t], dtype=np.int64) + base
            a = a[a >= pos]
            if t not in lengths:  # a message of no format: pymavlink's indexer stopped before it
                continue
            a = a[a + lengths[t] <= end]  # the last message may be cut by the block's end: the next block has it
            if not a.size:
                continue
            last = max(last, int(a[-1]) + lengths[t])
            counts[t] += a.size
            if t == 0x80:
                for o in a.tolist():
                    rec = r.data_map[o:o + fmt_len]
                    lengths[rec[3]] = rec[4]
                    names[rec[3]] = rec[5:9].split(b"\0", 1)[0].decode("ascii", "replace")
                    prefix += rec
            if names.get(t) in keep:
                kept.setdefault(t, []).append(a)
        del buf, found
        _give_back(r.data_map, pos, end)
        if last <= pos:
            break  # no whole message in the block: where pymavlink's indexer stops
        pos = last
    offsets = [np.concatenate(kept[t]) if t in kept else [] for t in range(256)]
    return offsets, counts


def _base(name: str) -> str:
    return name.split("[", 1)[0]


def _value(msg, name: str) -> float:
    if "[" in name:
        base, idx = name[:-1].split("[", 1)
        return float(getattr(msg, base)[int(idx)])
    return float(getattr(msg, name))


DATAFLASH_BLOCK_BYTES = 4 << 20  # a DataFlash log is indexed this much at a time
_DF_KEEP = ("FMT", "FMTU", "UNIT", "MULT", "PARM", "MODE", "ARM", "EV")  # messages whose offsets are always kept


def _read_dataflash(mavutil, path: Path, wanted: dict[str, set[str]], budget: Budget) -> AutopilotLog:
    """pymavlink's DataFlash reader indexes the file and parses its formats (FMT, FMTU, UNIT, MULT); the
    messages named are then unpacked from its index with each format's own struct and multipliers (a
    message object per sample costs 0.3 ms, measured: 44 s for a 10-minute log of 117,000 messages). The
    index is built by pymavlink's own indexer (:mod:`pymavlink.dfindexer`) a block at a time
    (:func:`_index_blocks`): it keeps the offsets of the messages named and of :data:`_DF_KEEP` only, and
    counts the others."""

    from pymavlink import DFReader

    class Reader(DFReader.DFReader_binary):
        counts: list[int] | None = None

        def init_arrays_fast(self, progress_callback=None):
            offsets, self.counts = _index_blocks(self, set(wanted) | set(_DF_KEEP))
            real = DFReader.dfindexer

            class Indexed:  # pymavlink's indexing after its build_offsets: FMT, UNIT, MULT, FMTU, first messages
                @staticmethod
                def build_offsets(*a, **k):
                    return offsets

            DFReader.dfindexer = Indexed
            try:
                super().init_arrays_fast(progress_callback)
            finally:
                DFReader.dfindexer = real

        def init_clock(self):  # the boot clock (TimeUS) is the time base: no search for a GPS clock
            self.init_clock_usec()

    r = Reader(str(path))
    out = AutopilotLog(path, "DataFlash")
    counts = dict(enumerate(r.counts if r.counts is not None else [len(offs) for offs in r.offsets]))
    for tid, fmt in r.formats.items():
        if counts.get(tid, 0) or fmt.name in wanted:
            out.fields[fmt.name] = list(fmt.columns)
            if getattr(fmt, "units", None):  # FMTU units: pymavlink 2.4.42 and later
                out.units[fmt.name] = {c: u for c, u in zip(fmt.columns, fmt.units) if u}

    def rows(name: str, cols: list[str]):
        """(TimeUS in s, instances or None, [values of each of cols]) of every message ``name``, in file order."""
        tid = r.name_to_id.get(name)
        if tid is None or "TimeUS" not in out.fields.get(name, ()):
            return np.zeros(0), None, [np.zeros(0) for _ in cols]
        fmt = r.formats[tid]
        bad = next((c for c in cols if c not in fmt.colhash), None)
        if bad is not None:
            raise Error(f"{path}: message {name} field {bad!r}: DataFlash fields are named whole (no [index])")
        offs = np.asarray(r.offsets[tid], dtype=np.int64)
        offs = offs[offs + fmt.len <= r.data_len]  # not a message cut short at the end
        codes = re.findall(r"\d*[A-Za-z?]", fmt.msg_struct.lstrip("<"))
        dt = np.dtype([(f"f{k}", "<" + (f"S{c[:-1]}" if c.endswith("s") else _NUMPY[c])) for k, c in enumerate(codes)])
        body = np.empty((offs.size, fmt.len - 3), np.uint8)
        raw = np.frombuffer(r.data_map, np.uint8)
        step = np.arange(3, fmt.len)
        i = 0
        while i < offs.size:  # gathered from the file a block at a time (at most 16,384 messages, 1 MB of file)
            j = min(i + 16384, int(np.searchsorted(offs, offs[i] + (1 << 20))), offs.size)
            o = offs[i:j]
            body[i:j] = raw[o[:, None] + step]
            _give_back(r.data_map, int(o[0]), int(o[-1]) + fmt.len)
            i = j
        del raw
        a = body.reshape(-1).view(dt)

        def col(c):
            k = fmt.colhash[c]
            v = a[f"f{k}"]
            if v.dtype.kind == "S":
                return [x.split(b"\0", 1)[0].decode("ascii", "replace") for x in v]
            v = v.astype(float)
            return v * fmt.msg_mults[k] if fmt.msg_mults[k] is not None else v

        inst = fmt.instance_field or ("I" if "I" in fmt.colhash else None)
        return col("TimeUS") / 1e6, None if inst is None else col(inst).astype(int), [col(c) for c in cols]

    _, _, (names, values) = rows("PARM", ["Name", "Value"])
    out.params.update(zip(names, map(float, values)))
    mode_field = "ModeNum" if "ModeNum" in out.fields.get("MODE", ()) else "Mode"
    t, _, (v,) = rows("MODE", [mode_field])
    events = [(tt, 1, None, int(x)) for tt, x in zip(t, v)]
    t, _, (v,) = rows("ARM", ["ArmState"]) if "ARM" in out.fields else rows("EV", ["Id"])
    if "ARM" in out.fields:
        events += [(tt, 0, bool(x), None) for tt, x in zip(t, v)]
    else:
        events += [(tt, 0, int(x) == _EV_ARMED, None) for tt, x in zip(t, v) if int(x) in (_EV_ARMED, _EV_DISARMED)]
    armed, mode = False, None
    for t, kind, a, md in sorted(events, key=lambda e: (e[0], e[1])):
        if kind == 1:
            mode = md
        else:
            armed = a
            out.arming_logged = True
        out.changes.append((float(t), armed, mode))
    named = [(name, [n for n in sorted(wanted[name]) if _base(n) in out.fields[name]]) for name in wanted
             if name in out.fields]
    count = {name: len(r.offsets[r.name_to_id[name]]) if name in r.name_to_id else 0 for name, _ in named}
    budget.check(sum(count[name] * (1 + len(cols)) for name, cols in named), str(path),
                 f"{sum(count.values()):,} messages ({', '.join(f'{n} {c:,}' for n, c in count.items())})")
    for name, cols in named:
        t, inst, vals = rows(name, cols)
        for i in ([None] if inst is None else sorted(set(inst.tolist()))):
            k = slice(None) if i is None else inst == i
            if i is not None:
                out.instances.setdefault(name, set()).add(i)
            out.tables[(name, i)] = (t[k], {c: v[k] for c, v in zip(cols, vals)})
    for t in [t for t, _ in out.tables.values()] + [np.array([c[0] for c in out.changes])]:
        if t.size:  # the log's span: its first and last message of those read
            out.t_first, out.t_last = min(out.t_first, float(t.min())), max(out.t_last, float(t.max()))
    return out


# MAVLink messages decoded whatever the mapping names: HEARTBEAT, SYSTEM_TIME, PARAM_VALUE, ATTITUDE (boot times)
_TLOG_ALWAYS = (0, 2, 22, 30)


TLOG_BLOCK_BYTES = 8 << 20  # a telemetry log is read this much at a time


def _tlog_frames(data: bytes, i: int = 0):
    """(start, end, system id, message id) of the frames of ``data`` from ``i`` on (each an 8-byte time, then a
    MAVLink 1 or 2 frame), up to the first frame cut short by its end; then the offset where that frame
    starts, or -1 where ``data`` is not framed there (a damaged stretch)."""
    n = len(data)
    while i + 16 <= n:
        k = i + 8
        if data[k] == 0xFD:  # MAVLink 2: header 10, CRC 2, signature 13 when signed
            if k + 10 > n:
                break  # a header cut short at the end of the block
            size = 12 + data[k + 1] + (13 if data[k + 2] & 1 else 0)
            sid, mid = data[k + 5], data[k + 7] | data[k + 8] << 8 | data[k + 9] << 16
        elif data[k] == 0xFE:  # MAVLink 1: header 6, CRC 2
            size, sid, mid = 8 + data[k + 1], data[k + 3], data[k + 5]
        else:
            yield -1
            return
        if k + size > n:
            break  # a frame cut short at the end of the block
        yield k, k + size, sid, mid
        i = k + size
    yield i


def _read_tlog(mavutil, path: Path, wanted: dict[str, set[str]], budget: Budget) -> AutopilotLog:
    """The file is read in blocks of :data:`TLOG_BLOCK_BYTES`; only the frames of the messages named (and
    those of :data:`_TLOG_ALWAYS`) are decoded, by pymavlink (which checks each frame's CRC and skips a
    damaged one), their values kept in float64 arrays as they come (checked against ``budget``). A file not
    framed throughout is read again by pymavlink's robust parser, whole."""
    seen: dict[int, _Vehicle] = {}  # system id -> what it sent (one pass; the vehicle is chosen at the end)

    def vehicle(sid: int) -> _Vehicle:
        if sid not in seen:
            seen[sid] = _Vehicle(AutopilotLog(path, "MAVLink telemetry"), budget)
        return seen[sid]

    mavutil.set_dialect("ardupilotmega")
    mod = mavutil.mavlink
    mav = mod.MAVLink(None)
    ids = {cls.id for cls in mod.mavlink_map.values() if cls.msgname in wanted} | set(_TLOG_ALWAYS)
    known: set[tuple[int, int]] = set()  # (system id, message id) whose fields are noted
    framed = True
    with open(path, "rb") as f:
        rest = b""
        while framed:
            chunk = f.read(TLOG_BLOCK_BYTES)
            data = rest + chunk
            for fr in _tlog_frames(data):
                if isinstance(fr, int):
                    framed = fr >= 0
                    rest = data[fr:] if framed else b""
                    break
                a, b, sid, mid = fr
                cls = mod.mavlink_map.get(mid)
                if cls is None:
                    continue
                if (sid, mid) not in known:
                    known.add((sid, mid))
                    vehicle(sid).saw(cls.msgname, cls.fieldnames, getattr(cls, "fieldunits_by_name", {}))
                if mid in ids:
                    try:
                        m = mav.decode(bytearray(data[a:b]))
                    except mod.MAVError:
                        continue  # a damaged frame (its CRC)
                    seen[sid].add(m, wanted, path)
            if not chunk:
                break
    if not framed:
        seen.clear()
        r = mavutil.mavlink_connection(str(path), robust_parsing=True, dialect="ardupilotmega")
        while True:
            m = r.recv_msg()
            if m is None:
                break
            if m.get_type() != "BAD_DATA":
                vehicle(m.get_srcSystem()).add(m, wanted, path)
    vehicles = sorted(k for k, v in seen.items() if v.ardupilot)
    if not vehicles:
        raise Error(f"{path}: no HEARTBEAT from an ArduPilot autopilot: not an ArduPilot vehicle's telemetry")
    if len(vehicles) > 1:
        raise Error(f"{path}: the telemetry of {len(vehicles)} ArduPilot vehicles (system ids "
                    f"{', '.join(map(str, vehicles))}); keep one vehicle's messages per log")
    v = seen[vehicles[0]]
    out = v.out
    for name, cc in v.rows.items():
        t = np.frombuffer(cc[0], dtype=float)
        out.tables[(name, None)] = (t, {n: np.frombuffer(c, dtype=float) for n, c in zip(sorted(wanted[name]), cc[1:])})
        out.t_first, out.t_last = min(out.t_first, float(t[0])), max(out.t_last, float(t[-1]))
    return out


class _Vehicle:
    """The messages of one MAVLink system id, on its boot clock."""

    def __init__(self, out: AutopilotLog, budget: Budget):
        self.out = out
        self.budget = budget
        self.kept = 0  # values in rows
        self.left = budget.values - budget.used  # values the budget leaves
        self.rows: dict[str, list[array]] = {}  # message -> its times, then each field named (sorted), float64
        self.sorted: dict[str, list[str]] = {}
        self.last: dict[str, float] = {}
        self.wrap: dict[str, float] = {}
        self.boot: float | None = None  # the boot time of the latest message that carried time_boot_ms
        self.state: tuple | None = None  # (armed, mode) of the latest autopilot heartbeat
        self.ardupilot = False

    def names(self, name: str, wanted: dict[str, set[str]]) -> list[str]:
        """The fields of ``name`` kept, in the order of its columns."""
        if name not in self.sorted:
            self.sorted[name] = sorted(wanted[name])
        return self.sorted[name]

    def saw(self, name: str, fields, units) -> None:
        if name not in self.out.fields:
            self.out.fields[name] = list(fields)
            self.out.units[name] = dict(units or {})

    def add(self, m, wanted: dict[str, set[str]], path: Path) -> None:
        out = self.out
        name = m.get_type()
        self.saw(name, m.get_fieldnames(), getattr(m, "fieldunits_by_name", {}))
        if name == "HEARTBEAT":  # a companion computer's or a camera's heartbeat names no autopilot
            if int(m.autopilot) == _AUTOPILOT_ARDUPILOT:
                self.ardupilot = True
                state = (bool(int(m.base_mode) & _ARMED_FLAG), int(m.custom_mode))
                if self.boot is not None and state != self.state:
                    self.state = state
                    out.arming_logged = True
                    out.changes.append((self.boot, *state))
            return
        if name == "PARAM_VALUE":
            pid = m.param_id
            out.params[pid.decode() if isinstance(pid, bytes) else str(pid)] = float(m.param_value)
        tb = getattr(m, "time_boot_ms", None)
        if tb is not None:
            self.boot = float(tb) / 1e3
            out.t_first, out.t_last = min(out.t_first, self.boot), max(out.t_last, self.boot)
        if name not in wanted:
            return
        tf = next((f for f in ("time_boot_ms", "time_usec") if hasattr(m, f)), None)
        if tf is None:
            raise Error(f"{path}: message {name} carries no boot time (time_boot_ms or time_usec)")
        t = float(getattr(m, tf)) / BOOT_TIME_FIELDS[tf]
        if tf == "time_usec" and "uint32_t" in _type_of(m, tf):  # 32 bits of microseconds wrap after 71.6 min
            t += self.wrap.get(name, 0.0)
            if name in self.last and t < self.last[name] - 2.0 ** 31 / 1e6:
                self.wrap[name] = self.wrap.get(name, 0.0) + 2.0 ** 32 / 1e6
                t += 2.0 ** 32 / 1e6
        if t > _UNIX_TIME_S:
            raise Error(f"{path}: message {name}: {tf} = {getattr(m, tf)} is a Unix time, not the autopilot's boot "
                        f"clock")
        if name == "SERVO_OUTPUT_RAW" and int(getattr(m, "port", 0)) != 0:
            return
        if self.last.get(name) == t:
            return  # the same message again (a repeated transmission)
        self.last[name] = t
        cols = self.rows.get(name)
        if cols is None:
            cols = self.rows[name] = [array("d") for _ in range(1 + len(wanted[name]))]
        if self.kept + len(cols) > self.left:
            self.budget.check(self.kept + len(cols), str(path), f"{self.kept + len(cols):,} values (by {name} at "
                                                                f"{t:.3f} s on the boot clock)")
        cols[0].append(t)
        for c, n in zip(cols[1:], self.names(name, wanted)):
            c.append(_value(m, n))
        self.kept += len(cols)


def _type_of(m, name: str) -> str:
    try:
        return m.fieldtypes[m.get_fieldnames().index(name)]
    except (AttributeError, ValueError, IndexError):
        return ""


def table(log: AutopilotLog, message: str, instance: int | None, mapping: str):
    """(t, {field: values}) of one message (and DataFlash instance); Error if it has none or is ambiguous."""
    present = sorted(log.instances.get(message, ()))
    if instance is not None:
        if log.kind != "DataFlash" or not present:
            raise Error(f"{log.path}: message {message} has no instances (instance = {instance} in {mapping})")
        if instance not in present:
            raise Error(f"{log.path}: message {message} has no instance {instance} (it has "
                        f"{', '.join(map(str, present))}; instance in {mapping})")
    elif len(present) > 1:
        raise Error(f"{log.path}: message {message} has instances {', '.join(map(str, present))}: say which with "
                    f"`instance` in {mapping}")
    elif present:
        instance = present[0]
    key = (message, instance)
    if key not in log.tables:
        raise Error(f"{log.path}: message {message} holds no sample")
    return log.tables[key]


def segments(log: AutopilotLog, which: str, modes: tuple[str, ...] | None) -> list[Segment]:
    """The stretches of the log (boot clock) that ``which`` selects: ``"all"`` the whole log; ``"armed"`` every
    stretch armed, and with ``modes`` (names or numbers) only while in one of them."""
    if which == "all":
        return [Segment(log.t_first, log.t_last, ("all",))]
    if not log.arming_logged:
        raise Error(f"{log.path}: no arming is logged (DataFlash ARM or EV messages, MAVLink HEARTBEAT): "
                    f"say [log] segment = \"all\"")
    want = None if modes is None else {m.upper() for m in modes}
    out = []
    start, seen = None, []
    changes = list(log.changes) + [(log.t_last, False, None)]
    for i, (t, armed, mode) in enumerate(changes):
        inside = armed and (want is None or mode_name(mode) in want or str(mode) in want)
        if inside and start is None:
            start, seen = t, []
        if inside and mode_name(mode) not in seen:
            seen.append(mode_name(mode))
        if not inside and start is not None:
            if t > start:
                out.append(Segment(start, t, tuple(seen)))
            start = None
    return out
