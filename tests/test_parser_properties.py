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
    if c.number is not None and objectives.get(name).nonnegative:  # never a bound that cannot matter
        assert (op == "<=" and c.number >= 0) or (op == ">=" and c.number > 0)


T = np.arange(0.0, 5.0 + 1e-9, 0.05)


@pytest.fixture(scope="module")
def pose(tmp_path_factory):
    d = tmp_path_factory.mktemp("map")
    a = np.stack([T, 0.1 * T, 0 * T, 0 * T, 0 * T, 0 * T, 1 + 0 * T, -9.8 + 0 * T], 1)
    np.savetxt(d / "pose.csv", a, delimiter=",", header="t,px,qx,qy,qz,qw1,qw,az", comments="", fmt="%.9g")
    return d


_frames = st.sampled_from(['"ned"', '"enu"', '"nwu"', '"frd"', '"flu"', '"up"', "1", "true"])
_orders = st.sampled_from(['"xyzw"', '"wxyz"', '"zyxw"', "4"])
_units = st.sampled_from(['"m"', '"mm"', '"furlong"', '"s"', '""', "1"])
_cols = st.sampled_from(['["px", "px", "px"]', '["px", "qx"]', '["nope", "px", "px"]', '"px"', "[]",
                         '["px", "qx", "qy"]', '["px", "qz", "qx"]'])
_quats = st.sampled_from(['["qx", "qy", "qz", "qw"]', '["qw", "qx", "qy", "qz"]', '["qx", "qy", "qz"]',
                          '["qx", "qy", "qz", "qw1"]', '["qx", "qx", "qy", "qz"]'])
_extra = st.sampled_from(["", "passive = true", 'passive = "yes"', "rate = -1.0", "rate = 1e9", "max_gap = 0.0"])


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(_frames, _frames, _orders, _units, _cols, _quats, _extra, st.booleans())
def test_any_log_mapping_loads_or_is_one_line(pose, world, body, order, unit, cols, quat, extra, accel):
    text = f'''[log]
name = "p"
{extra if "passive" in extra else "passive = true"}
{"" if "passive" in extra else extra}
rate = 10.0

[[stream]]
file = "pose.csv"
time = "t"
world = {world}
body = {body}
quaternion_order = {order}
position = {{ columns = {cols}, unit = {unit} }}
quaternion = {{ columns = {quat} }}
{'acceleration = { columns = ["qx", "qy", "az"], unit = "m/s^2" }' if accel else ""}
'''
    m = pose / "p.log.toml"
    m.write_text(text)
    try:
        lg = load_log(m)
    except LogError as e:
        assert "\n" not in str(e) and str(e), e
        return
    assert lg.duration == pytest.approx(5.0) and all(np.isfinite(v).all() for v in lg.signals.values())


def test_the_mapping_drawn_from_valid_values_loads(pose):
    """The property above is not vacuous: its valid corner loads."""
    test_any_log_mapping_loads_or_is_one_line.hypothesis.inner_test(
        pose, '"ned"', '"frd"', '"xyzw"', '"m"', '["px", "qz", "qx"]', '["qx", "qy", "qz", "qw"]', "", True)
    lg = load_log(pose / "p.log.toml")
    assert lg.duration == pytest.approx(5.0)
