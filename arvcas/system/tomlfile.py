"""Reading TOML input files with one-line errors that name the file (params, scenario, studies)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

__all__ = ["read_text", "parse"]


def read_text(path: str | Path, error: type[ValueError], what: str = "file") -> str:
    """The UTF-8 text of ``path`` (:func:`arvcas.util.files.read_text`: regular files only, never blocking on
    a FIFO, a size cap, no byte-order mark); any problem raises ``error`` naming the file."""
    from arvcas.util.files import read_text as _read

    return _read(path, what, error)


def parse(text: str, where: str, error: type[ValueError]) -> dict[str, Any]:
    """Parse TOML text; a syntax error raises ``error`` naming ``where`` and the position."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{where}: malformed TOML: {' '.join(str(e).split())}") from None
