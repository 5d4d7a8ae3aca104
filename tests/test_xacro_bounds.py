"""A xacro expansion is bounded: a macro that expands exponentially (2^40 elements), one that calls itself
without end, or an expansion that runs too long stops in one line naming the file and the bound, before
any import work; a real description (the RexROV 2 + Oberon 7) stays far inside every bound."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("xacro")

from arvcas.cli import main  # noqa: E402
from arvcas.system import rosfiles, uuv  # noqa: E402

from trust_helpers import XACRO_EXPRESSIONS, XACRO_RECURSIVE, xacro_bomb  # noqa: E402

DATA = Path(__file__).parent / "data" / "uuv_rexrov2"


@pytest.mark.parametrize("text, words", [
    (xacro_bomb(40), ["the expansion passed 20,000 elements", "MAX_XACRO_ELEMENTS"]),
    (XACRO_RECURSIVE, ["elements nested more than 100 deep", "MAX_XACRO_DEPTH"]),
])
def test_an_unbounded_expansion_is_one_line_and_writes_nothing(tmp_path, capsys, text, words):
    src = tmp_path / "bomb.xacro"
    src.write_text(text)
    out = tmp_path / "x.toml"
    assert main(["import-system", "uuv", str(src), "--out", str(out), "--max-thrust", "100"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"arvcas: error: {src}: xacro: ") and not out.exists(), err
    assert all(w in err for w in words), err


def test_the_time_bound(tmp_path, monkeypatch):
    src = tmp_path / "small.xacro"
    src.write_text(xacro_bomb(3))
    assert uuv.expand(src, {}, {})[0].count("<link") == 8  # 2^3 links: within every bound
    monkeypatch.setattr(rosfiles, "MAX_XACRO_SECONDS", 0.0)
    with pytest.raises(uuv.ImportError_, match=r"xacro: the expansion took more than 0 s after 1 elements; refused"):
        uuv.expand(src, {}, {})


def test_a_bounded_expansion_just_below_the_element_bound_and_the_real_descriptions_pass(tmp_path, monkeypatch):
    import xacro

    src = tmp_path / "b.xacro"
    src.write_text(xacro_bomb(6))  # 2^6 links
    monkeypatch.setattr(rosfiles, "MAX_XACRO_ELEMENTS", 1000)
    assert uuv.expand(src, {}, {})[0].count("<link") == 64
    monkeypatch.setattr(rosfiles, "MAX_XACRO_ELEMENTS", 64)  # every link is one element: 64 are not enough
    with pytest.raises(uuv.ImportError_, match="the expansion passed 64 elements"):
        uuv.expand(src, {}, {})
    monkeypatch.undo()
    text, _ = uuv.expand(DATA / "rexrov2_description" / "robots" / "rexrov2_oberon7.xacro", uuv.find_packages([DATA]), {})
    assert "oberon7" in text and xacro.eval_all.__name__ == "eval_all"  # xacro is left as it was


@pytest.mark.parametrize("tag", list(XACRO_EXPRESSIONS))
def test_an_expression_without_end_is_stopped_by_the_time_and_memory_bounds(tmp_path, capsys, monkeypatch, tag):
    import time

    monkeypatch.setattr(rosfiles, "MAX_XACRO_SECONDS", 1.0)
    src = tmp_path / "expr.xacro"
    src.write_text(XACRO_EXPRESSIONS[tag])
    out = tmp_path / "x.toml"
    t0 = time.monotonic()
    assert main(["import-system", "uuv", str(src), "--out", str(out), "--max-thrust", "100"]) == 2
    took = time.monotonic() - t0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"arvcas: error: {src}: xacro: ") and not out.exists(), err
    assert took < 1.0 + rosfiles.XACRO_GRACE_SECONDS + 30, took  # killed at its bound, not run to its end
    if tag != "repeat":  # xacro reports the MemoryError of a repetition in its own words, at once
        assert "refused (arvcas.system.rosfiles.MAX_XACRO_" in err, err
