"""Parsed logs kept in the build cache, so that a trial read once is not parsed again.

Reading a trial is most of the time of validating it (``results/validation/speed.json``): a ROS 2 bag's
messages are deserialised one by one, and the joints' smoothing splines are fitted on every read. A log
read by :func:`arvcas.ident.logs.load_log` is stored as an ``.npz`` file (no pickle) under
``<cache>/logs/`` (:func:`arvcas.build.codegen.cache_dir`), keyed by the SHA-256 of

* the source of the modules that parse logs (this one, :mod:`arvcas.ident.logs` and its readers
  :mod:`arvcas.ident.streams` and :mod:`arvcas.ident.ardupilot`, :mod:`arvcas.system.config`),
* the mapping file's path as given, its bytes, and the system's joint count and thruster names it was checked
  against,
* the bytes of every file the mapping names: each string value of the mapping that is the name of a file or a
  directory next to it (a directory: every file below it; a mapping that names its own directory or one above
  it, or more than :data:`MAX_FILES` files, is not cached).

Any change to any of them reads the log again. A mapping that does not load raises as
:func:`arvcas.ident.logs.load_log` does (it is never cached); a cache that cannot be written or read is
passed by (the log is read from its files).
"""

from __future__ import annotations

import hashlib
import json
import os
import tomllib
from pathlib import Path

import numpy as np

from arvcas.ident import logs as logs_mod

__all__ = ["load_log", "load_logs"]

FORMAT = "arvcas-log-cache-1"


def _code_digest() -> str:
    from arvcas.ident import ardupilot, streams
    from arvcas.system import config

    h = hashlib.sha256(FORMAT.encode())
    for mod in (logs_mod, streams, ardupilot, config):
        h.update(Path(mod.__file__).read_bytes())
    h.update(Path(__file__).read_bytes())
    return h.hexdigest()


_CODE: list[str] = []


MAX_FILES = 1000  # a mapping naming more files than this (a directory of many) is not cached


class _NotCached(Exception):
    pass


def _named_files(mapping: Path, text: str) -> list[Path]:
    """Every file the mapping's string values name, relative to its directory (directories: their files).
    :class:`_NotCached` for a value naming the mapping's own directory or one above it, or too many files."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        return []
    home = mapping.parent.resolve()
    out: set[Path] = set()

    def walk(v):
        if isinstance(v, dict):
            for x in v.values():
                walk(x)
        elif isinstance(v, list):
            for x in v:
                walk(x)
        elif isinstance(v, str) and v and "\n" not in v and len(v) < 4096:
            try:
                p = mapping.parent / v
                if p.is_file():
                    out.add(p)
                elif p.is_dir():
                    if home.is_relative_to(p.resolve()):
                        raise _NotCached
                    for q in p.rglob("*"):
                        if q.is_file():
                            out.add(q)
                            if len(out) > MAX_FILES:
                                raise _NotCached
            except (OSError, ValueError):
                pass

    walk(doc)
    return sorted(out)


def _key(path: Path, n_joints, thruster_names) -> str | None:
    try:
        raw = path.read_bytes()
        text = raw.decode("utf-8-sig")
    except (OSError, UnicodeDecodeError):
        return None
    if not _CODE:
        _CODE.append(_code_digest())
    h = hashlib.sha256(_CODE[0].encode())
    h.update(json.dumps([str(path), n_joints, list(thruster_names) if thruster_names is not None else None]).encode())
    h.update(hashlib.sha256(raw).digest())
    try:
        named = _named_files(path, text)
    except _NotCached:
        return None
    for f in named:
        try:
            h.update(f"{f.relative_to(path.parent).as_posix()}\0".encode())
            h.update(hashlib.sha256(f.read_bytes()).digest())
        except (OSError, ValueError):
            return None
    return h.hexdigest()


def _entry(key: str) -> Path | None:
    from arvcas.build.codegen import CacheError, cache_dir

    try:
        d = cache_dir() / "logs"
        d.mkdir(mode=0o700, exist_ok=True)
    except (CacheError, OSError):
        return None
    return d / f"{key}.npz"


def _pack(lg: logs_mod.Log) -> dict[str, np.ndarray]:
    jt = lg.joints
    meta = {"name": lg.name, "path": lg.path, "system": lg.system, "source": lg.source, "t0": lg.t0, "std": lg.std,
            "signals": list(lg.signals), "thrust": list(lg.thrust), "command": list(lg.command),
            "command_unit": lg.command_unit, "wrench": lg.wrench is not None, "payload": lg.payload is not None,
            "passive": lg.passive, "files": list(lg.files),
            "joints": None if jt is None else {"names": list(jt.names), "smoothing": list(jt.smoothing),
                                               "cutoff": jt.cutoff, "k": [int(s.k) for s in jt.splines],
                                               "extrapolate": [s.extrapolate for s in jt.splines]}}
    a = {"meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), "t": lg.t}
    a.update({f"signal.{n}": v for n, v in lg.signals.items()})
    a.update({f"thrust.{n}": v for n, v in lg.thrust.items()})
    a.update({f"command.{n}": v for n, v in lg.command.items()})
    if lg.wrench is not None:
        a["wrench"] = lg.wrench
    if lg.payload is not None:
        a["payload"] = lg.payload
    if jt is not None:
        for i, s in enumerate(jt.splines):
            a[f"knots.{i}"], a[f"coef.{i}"], a[f"raw_t.{i}"], a[f"raw_q.{i}"] = s.t, s.c, jt.raw_t[i], jt.raw_q[i]
    return a


def _unpack(z) -> logs_mod.Log:
    from scipy.interpolate import BSpline

    meta = json.loads(bytes(z["meta"]).decode())
    jt = None
    if meta["joints"] is not None:
        j = meta["joints"]
        n = len(j["names"])
        sp = tuple(BSpline(z[f"knots.{i}"], z[f"coef.{i}"], j["k"][i], extrapolate=j["extrapolate"][i]) for i in range(n))
        jt = logs_mod.JointTrajectory(tuple(j["names"]), sp, tuple(j["smoothing"]), j["cutoff"],
                                      tuple(z[f"raw_t.{i}"] for i in range(n)), tuple(z[f"raw_q.{i}"] for i in range(n)))
    return logs_mod.Log(
        name=meta["name"], path=meta["path"], system=meta["system"], source=meta["source"], t=z["t"], t0=meta["t0"],
        signals={n: z[f"signal.{n}"] for n in meta["signals"]}, std=meta["std"], joints=jt,
        thrust={n: z[f"thrust.{n}"] for n in meta["thrust"]}, command={n: z[f"command.{n}"] for n in meta["command"]},
        command_unit=meta["command_unit"], wrench=z["wrench"] if meta["wrench"] else None,
        payload=z["payload"] if meta["payload"] else None, passive=meta["passive"], files=tuple(meta["files"]))


def load_log(path, n_joints: int | None = None, thruster_names: tuple[str, ...] | None = None) -> logs_mod.Log:
    """:func:`arvcas.ident.logs.load_log`, from the cache when the mapping and every file it names are unchanged."""
    p = Path(path)
    key = _key(p, n_joints, thruster_names)
    entry = None if key is None else _entry(key)
    if entry is not None and entry.is_file():
        try:
            with np.load(entry, allow_pickle=False) as z:
                return _unpack(z)
        except (OSError, ValueError, KeyError, TypeError):
            pass  # unreadable: read the log again and replace the entry
    lg = logs_mod.load_log(p, n_joints, thruster_names)
    if entry is not None:
        tmp = entry.with_name(f"{entry.stem}.{os.getpid()}.tmp")
        try:
            with open(tmp, "wb") as f:
                np.savez(f, **_pack(lg))
            os.replace(tmp, entry)
        except OSError:
            tmp.unlink(missing_ok=True)
    return lg


def load_logs(paths, n_joints: int | None = None, thruster_names: tuple[str, ...] | None = None) -> list[logs_mod.Log]:
    """:func:`arvcas.ident.logs.load_logs` through the cache: every log read and checked, names must differ."""
    out = [load_log(p, n_joints, thruster_names) for p in paths]
    names = [lg.name for lg in out]
    for i, lg in enumerate(out):
        if lg.name in names[:i]:
            first = out[names.index(lg.name)]
            raise logs_mod.LogError(f"{lg.path}: trial name {lg.name!r} is also the name of {first.path}")
    return out
