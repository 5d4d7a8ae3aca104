"""Reading TOML input files with one-line errors that name the file (params, scenario, studies)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

__all__ = ["read_text", "parse"]


def read_text(path: str | Path, error: type[ValueError], what: str = "file") -> str:
    """The UTF-8 text of ``path``; a missing, unreadable, directory or non-UTF-8 path raises ``error``."""
    p = Path(path)
    where = str(p)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise error(f"{where}: {what} not found") from None
    except IsADirectoryError:
        raise error(f"{where}: is a directory, expected a TOML {what}") from None
    except OSError as e:
        raise error(f"{where}: cannot read {what} ({e.strerror})") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise error(f"{where}: not UTF-8 text (line {line}, byte {e.start})") from None


def parse(text: str, where: str, error: type[ValueError]) -> dict[str, Any]:
    """Parse TOML text; a syntax error raises ``error`` naming ``where`` and the position."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{where}: malformed TOML: {' '.join(str(e).split())}") from None
