"""The fingerprint of the code and data that define arvcas's models and runs.

:func:`model_hash` is a sha256 over the bytes of every file that shapes a compiled graph or a
simulated number: the model layer (``arvcas/model``), the simulation layer (``arvcas/sim``), the
controllers (``arvcas/controllers``), code generation (``arvcas/build/codegen.py``, its batch loop ``arvcas/build/batchloop.py``, the lane rewrite ``arvcas/build/lanes.py``), the parameter and
configuration readers, and the packaged data files (``arvcas/data``). It keys the compile cache (a
warm start loads a library without building its graph, :mod:`arvcas.build.codegen`).

Editing any of these files, even a comment, changes the hash: the cache rebuilds rather than risk a
stale library. That makes it too coarse to say whether a result is still valid: a front records the
digest of its compiled run instead (:meth:`arvcas.sim.run.CompiledRun.digest`, docs/provenance.md),
and this hash only as the source that wrote it (a file of an older arvcas is checked by it).
"""

from __future__ import annotations

import hashlib
import threading
from pathlib import Path

__all__ = ["model_hash", "model_files"]

_PKG = Path(__file__).resolve().parents[1]
# folders (every *.py and data file below them) and single files, relative to the package
_TREES = ("model", "sim", "controllers", "data")
_FILES = ("system/params.py", "system/tomlfile.py", "system/config.py", "build/codegen.py", "build/batchloop.py", "build/lanes.py", "build/provenance.py", "__init__.py")
_SUFFIXES = (".py", ".toml", ".urdf", ".json", ".csv")  # .csv: thrust tables (docs/system-file.md)

_LOCK = threading.Lock()
_MEMO: dict[tuple, str] = {}


def model_files() -> list[Path]:
    """The files :func:`model_hash` covers, sorted (absolute paths)."""
    out = []
    for t in _TREES:
        d = _PKG / t
        if d.is_dir():
            out += [p for p in d.rglob("*") if p.is_file() and p.suffix in _SUFFIXES and "__pycache__" not in p.parts]
    out += [_PKG / f for f in _FILES if (_PKG / f).is_file()]
    return sorted(set(out))


def model_hash() -> str:
    """sha256 (hex) of the model code and data of this installation (memoised on the files' mtimes and sizes)."""
    files = model_files()
    stamp = tuple((str(p), p.stat().st_mtime_ns, p.stat().st_size) for p in files)
    with _LOCK:
        h = _MEMO.get(stamp)
        if h is not None:
            return h
    sha = hashlib.sha256(b"arvcas-model-1")
    for p in files:
        rel = p.relative_to(_PKG).as_posix().encode()
        data = p.read_bytes()
        for part in (rel, data):
            sha.update(len(part).to_bytes(8, "little"))
            sha.update(part)
    h = sha.hexdigest()
    with _LOCK:
        _MEMO.clear()
        _MEMO[stamp] = h
    return h
