"""Shared by the identification and validation tests: a shipped system without its arm, as a system file."""

from __future__ import annotations

from pathlib import Path

import tomlkit

import arvcas


def vehicle_only(shipped: str, name: str, directory: Path):
    """``shipped`` with its arm, payload and defaults removed, renamed ``name``, written to ``directory`` and
    loaded (a vehicle-only system keeps the compiled code small)."""
    doc = tomlkit.parse(open(arvcas.load_system(shipped).path, encoding="utf-8").read())
    for k in ("arm", "payload", "defaults"):
        doc.pop(k, None)
    doc["system"]["name"] = name
    path = Path(directory) / f"{name}.toml"
    path.write_text(tomlkit.dumps(doc))
    return arvcas.load_system(path)
