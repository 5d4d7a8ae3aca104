"""The repository's scripts (benchmarks/, studies/, results/**) as modules, loaded by their paths: the checkout's
benchmarks/ is not a package on sys.path when the suite runs against an installed wheel."""

from __future__ import annotations

import importlib.util
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@lru_cache(maxsize=None)
def load_script(path: str | Path, name: str | None = None):
    """The module of the script at ``path`` (relative to the repository's root, or absolute), run once per
    process (so its own caches, such as step_accuracy's CVODES references, are shared by the tests that use it)."""
    path = ROOT / path
    spec = importlib.util.spec_from_file_location(name or path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
