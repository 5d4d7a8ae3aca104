"""Shared by the identification and validation tests: a shipped system without its arm, as a system file."""

from __future__ import annotations

from pathlib import Path

import tomlkit

import arvcas


def armless(shipped: str, directory: Path, name: str) -> Path:
    """``<directory>/<name>.toml``: the shipped system ``shipped`` without its arm, payload and defaults (a
    vehicle-only system keeps the compiled code small), named ``name``."""
    src = arvcas.load_system(shipped).path
    doc = tomlkit.parse(open(src, encoding="utf-8").read())
    for k in ("arm", "payload", "defaults"):
        doc.pop(k, None)
    doc["system"]["name"] = name
    path = Path(directory) / f"{name}.toml"
    path.write_text(tomlkit.dumps(doc), encoding="utf-8")
    return path


def vehicle_only(shipped: str, name: str, directory: Path):
    """:func:`armless`, loaded: the :class:`arvcas.System`."""
    return arvcas.load_system(armless(shipped, directory, name))
