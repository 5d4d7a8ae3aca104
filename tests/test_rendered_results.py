"""The generated pages of results/ are their scripts' renderings of the JSON committed beside them
(benchmarks/render_results.py): a page edited by hand, or a script's wording changed without re-rendering, fails."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_results_pages_are_their_rendering():
    """Every generated page of results/ is its script's rendering of the JSON committed beside it."""
    spec = importlib.util.spec_from_file_location("arvcas_render_results", ROOT / "benchmarks" / "render_results.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    stale = [page for page, text in mod.rendered().items() if (ROOT / page).read_text() != text]
    assert not stale, f"differ from their rendering (python benchmarks/render_results.py): {stale}"
