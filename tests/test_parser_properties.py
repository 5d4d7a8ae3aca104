"""Property tests of the readers a user's text reaches: any constraint expression is a Constraint that says
what its text says, or one ObjectiveError line; any log mapping (keys, frames, orders, units, columns drawn
from valid and invalid values) loads or is one LogError line, never another exception."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from arvcas.ident.logs import LogError, load_log
from arvcas.metrics import objectives

_names = st.sampled_from(["chat", "rmse", "energy", "peak_thrust", "iae", "excursion", "nope", "1x", "", "limit"])
_ops = st.sampled_from(["<=", ">=", "<", "==", "=<", ""])
_nums = st.sampled_from(["0", "-1", "0.8", "1e3", "-0.5", "nan", "inf", "1e999", "2.", ".5", "x", ""])
_rhs = st.one_of(_nums, st.builds(lambda a: f"{a} * limit", _nums), st.builds(lambda a: f"limit * {a}", _nums),
                 st.just("limit"), st.builds(lambda a, b: f"{a} * limit * {b}", _nums, _nums))


@settings(max_examples=400, deadline=None)
@given(_names, _ops, _rhs, st.sampled_from(["", " ", "  "]))
def test_any_constraint_text_is_parsed_faithfully_or_refused_in_one_line(name, op, rhs, sp):
    text = f"{sp}{name}{sp}{op}{sp}{rhs}{sp}"
    try:
        c = objectives.parse_constraint(text, "objectives.constraints")
    except objectives.ObjectiveError as e:
        msg = str(e)
        assert "\n" not in msg and msg.startswith("objectives.constraints: "), msg
        return
    assert c.objective == name and c.op == op and name in objectives.names()
    bound = c.number if c.number is not None else c.factor
    assert bound is not None and math.isfinite(bound)
    if objectives.get(name).nonnegative:  # never a bound (a number, or a factor of a limit >= 0) that cannot matter
        assert (op == "<=" and bound >= 0) or (op == ">=" and bound > 0)


_json = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False)
                     | st.text(), lambda kids: st.lists(kids, max_size=4)
                     | st.dictionaries(st.text(max_size=8), kids, max_size=4), max_leaves=12)


@settings(max_examples=100, deadline=None)
@given(_json, st.text())
def test_any_page_data_is_inert_inside_the_script_block_and_reads_back(doc, title):
    """front explore's page: whatever names and texts its data and title hold, the inline JSON has no
    character that can end or comment out the script block and reads back as the same document, and the
    title is HTML text (the page's markup is the template's alone)."""
    import html
    import json
    import re

    pytest.importorskip("plotly")
    from arvcas.experiments.explore import inline_json, page_html

    text = inline_json(doc)
    assert not set(text) & set("<>&") and text.isascii() and json.loads(text) == doc
    page = page_html({"title": title, "data": doc})
    blocks = re.findall(r'<script type="application/json" id="data">(.*?)</script>', page, re.S)
    assert len(blocks) == 1 and json.loads(blocks[0]) == {"title": title, "data": doc}
    t = page.split("<title>", 1)[1].split("</title>", 1)[0]  # the head's (plotly.js holds another)
    assert html.unescape(t) == title and not set(t) & set("<>")
    assert page.count("<script") == page_html({"title": "", "data": None}).count("<script")
