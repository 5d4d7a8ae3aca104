"""Compiled libraries shipped to processes without a compiler or a compile cache (Dask workers): the
client bundles the libraries of its run (:func:`bundle`: their bytes with their verified sha256), a worker
loads them (:func:`preload`) after checking that they fit its machine, its CasADi and its arvcas model
code; later :func:`arvcas.build.codegen.build_described` calls of the same description get them.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import sys
from pathlib import Path

import casadi as ca

from arvcas.build import codegen

__all__ = ["bundle", "preload", "platform_id", "process_name"]


def platform_id() -> dict:
    """What a compiled library needs of the machine that loads it."""
    import platform as _pf

    return {"system": sys.platform, "machine": _pf.machine(), "libc": " ".join(_pf.libc_ver()).strip(),
            "casadi": ca.__version__, "isa": list(codegen.isa_flags())}


def bundle(fns) -> dict:
    """The compiled libraries behind ``fns`` (Functions returned by :func:`build_described`) as bytes
    with their verified sha256, for :func:`preload` in another process."""
    from arvcas.build.provenance import model_hash

    items = []
    for f in fns:
        m = codegen.artifact_of(f)
        if m is None or "ident" not in m:
            raise codegen.CacheError(f"bundle: {f.name()} was not built by build_described; nothing to ship")
        data = Path(m["path"]).read_bytes()
        if hashlib.sha256(data).hexdigest() != m["so_sha256"]:
            raise codegen.CacheError(f"bundle: {m['path']} no longer matches its manifest; rebuild it")
        items.append({"name": m["name"], "ident": m["ident"], "so": data,
                      "manifest": {k: v for k, v in m.items() if k != "path"}})
    return {"format": "arvcas-bundle", "platform": platform_id(), "model_hash": model_hash(), "items": items}


def process_name() -> str:
    """This process, for messages: the Dask worker's name and address, else host and pid."""
    try:
        from distributed import get_worker

        w = get_worker()
        return f"worker {w.name} ({w.address})"
    except (ImportError, ValueError):
        import socket

        return f"process {os.getpid()} on {socket.gethostname()}"


def preload(b: dict) -> int:
    """Load the libraries of a :func:`bundle` in this process (no compiler, no cache needed); later
    :func:`build_described` calls of the same description get them. Returns how many were new.

    Refuses, one line naming this process (a Dask worker by name), libraries built for another
    platform or CasADi, or by other arvcas model code; each library's bytes are checked against its
    sha256 before loading.
    """
    from arvcas.build.provenance import model_hash

    here = process_name()
    if not isinstance(b, dict) or b.get("format") != "arvcas-bundle":
        raise codegen.CacheError(f"{here}: not an arvcas bundle of compiled libraries")
    mine, theirs = platform_id(), dict(b.get("platform", {}))
    need = theirs.pop("isa", [])
    mine.pop("isa")
    missing = [f for f in need if f not in codegen.supported_isa()]
    if missing:
        raise codegen.CacheError(f"{here}: the client's compiled libraries need {' '.join(missing)}, which this CPU lacks; "
                         f"build them on the client with {codegen.ISA_ENV}=baseline, or give the worker a compiler and arvcas's cache")
    if mine != theirs:
        diff = ", ".join(f"{k} {theirs.get(k)!r} here {mine.get(k)!r}" for k in mine if mine.get(k) != theirs.get(k))
        raise codegen.CacheError(f"{here}: the client's compiled libraries do not fit this machine ({diff}); "
                         f"run the worker on the client's platform or give it a compiler and arvcas's cache")
    if b.get("model_hash") != model_hash():
        raise codegen.CacheError(f"{here}: arvcas's model code or data differs from the client's (model hash "
                         f"{model_hash()[:12]} here, {str(b.get('model_hash'))[:12]} there); install the same arvcas")
    n = 0
    with codegen._LOCK:
        todo = [it for it in b["items"] if it["ident"] not in codegen._PRELOADED]
        if not todo:
            return 0
        from arvcas.util.files import private_dir

        d = private_dir("shipped")
        if not codegen._PRIVATE_DIRS:
            atexit.register(codegen._remove_private_dirs)
        codegen._PRIVATE_DIRS.append(d)
        for it in todo:
            data = it["so"]
            if hashlib.sha256(data).hexdigest() != it["manifest"].get("so_sha256"):
                raise codegen.CacheError(f"{here}: shipped library {it['name']} does not match its sha256; refusing to load it")
            so = d / f"{it['name']}-{it['ident'][:20]}.so"
            so.write_bytes(data)
            os.chmod(so, 0o500)
            try:
                f = ca.external(it["name"], str(so))
            except RuntimeError as e:
                why = next((ln.strip() for ln in str(e).splitlines() if ln.strip()), type(e).__name__)
                raise codegen.CacheError(f"{here}: shipped library {it['name']} does not load ({why[:160]})") from None
            codegen._KEEP.append(f)
            codegen._MANIFESTS[f.__hash__()] = dict(it["manifest"], path=str(so), shipped=True)
            codegen._PRELOADED[it["ident"]] = f
            n += 1
    return n
