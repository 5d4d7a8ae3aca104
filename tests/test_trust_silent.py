"""Values that were accepted silently and change the answer or nothing at all: each is now refused in one
line naming the key or argument, or warned naming the time and the run's length (the class, per place):
a constraint that can never hold (or always holds) on a non-negative objective, a hypervolume reference
point no member can dominate, negative nominal-model factors, a gain table with booleans or strings for
numbers, a task or waypoint after the run's end."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from arvcas.metrics import objectives
from arvcas.sim.scenario import ScenarioWarning, load_scenario
from trust_helpers import scenario_variant


# ---- constraints on objectives that are never negative ---------------------------------------------------

@pytest.mark.parametrize("name", [n for n in objectives.names() if objectives.get(n).nonnegative])
def test_constraints_that_never_hold_or_always_hold_are_refused(name):
    with pytest.raises(objectives.ObjectiveError, match=rf"^c: '{name} <= -0.5' can never hold: {name} is never "
                                                        rf"negative \(give a bound >= 0\)$"):
        objectives.parse_constraint(f"{name} <= -0.5", "c")
    for bound in ("0", "-3e2"):
        with pytest.raises(objectives.ObjectiveError, match=rf"always holds: {name} is never negative"):
            objectives.parse_constraint(f"{name} >= {bound}", "c")
    assert objectives.parse_constraint(f"{name} <= 0", "c").number == 0.0  # "is zero": a real constraint
    assert objectives.parse_constraint(f"{name} >= 1e-3", "c").number == 1e-3


@pytest.mark.parametrize("name", [n for n in objectives.names() if objectives.get(n).nonnegative
                                  and type(objectives.get(n)).limit is not objectives.Objective.limit])
@pytest.mark.parametrize("rhs, factor", [("-0.8 * limit", -0.8), ("limit * -2", -2.0), ("0 * limit", 0.0),
                                         ("1e-3*limit", 1e-3)])
def test_a_factor_of_the_limit_is_checked_as_a_bound_is(name, rhs, factor):
    """The limit of a never-negative objective is >= 0: a negative factor can never hold with <=, a factor
    at or below 0 always holds with >=."""
    le, ge = f"{name} <= {rhs}", f"{name} >= {rhs}"
    if factor < 0:
        with pytest.raises(objectives.ObjectiveError, match=rf"^c: .* can never hold: {name} is never negative "
                                                            r"\(give a factor >= 0\)$"):
            objectives.parse_constraint(le, "c")
    else:
        assert objectives.parse_constraint(le, "c").factor == factor
    if factor <= 0:
        with pytest.raises(objectives.ObjectiveError, match=rf"^c: .* always holds: {name} is never negative "
                                                            r"\(give a factor > 0\)$"):
            objectives.parse_constraint(ge, "c")
    else:
        assert objectives.parse_constraint(ge, "c").factor == factor


def test_every_built_in_objective_declares_its_sign_and_a_plugins_is_not_assumed():
    assert all(objectives.get(n).nonnegative for n in ("chat", "rmse", "iae", "energy", "peak_thrust",
                                                       "saturation_time", "settling_time", "excursion"))
    assert objectives.Objective.nonnegative is False  # a user's objective may be negative: no such check


# ---- the reference point of compare ---------------------------------------------------------------------

def test_compare_refuses_a_reference_point_no_member_can_dominate(tmp_path, capsys):
    from arvcas import cli
    from arvcas.tuning.front import Front
    from arvcas.tuning.compare import compare_fronts

    fr = _tiny_front()
    for ref, bad in (([-1.0, 2.0], "f_chat is -1"), ([2.0, 0.0], "f_rmse is 0")):
        with pytest.raises(ValueError, match=rf"^--ref: the reference point's {bad}, but .* is never negative: no "
                                             rf"member can dominate it \(give a value > 0\)$"):
            compare_fronts(fr, fr, ref=ref)
    assert compare_fronts(fr, fr, ref=[2.0, 2.0]).hv[0] > 0
    assert isinstance(fr, Front)


def _tiny_front():
    """A two-member front of the paper's objectives (no study run: the comparison reads only F, G, names)."""
    from arvcas.tuning.front import Front
    import dataclasses

    fields = {f.name for f in dataclasses.fields(Front)}
    kw = {k: None for k in fields}
    kw.update(F=np.array([[0.5, 1.5], [1.5, 0.5]]), G=np.zeros((2, 1)), objectives=("chat", "rmse"),
              controller="agsta", reference_point=np.array([2.0, 2.0]))
    from pathlib import Path

    kw["path"] = Path("/nowhere/agsta/front.h5")
    return Front(**{k: v for k, v in kw.items() if k in fields})


# ---- Run.many and the nominal-model factors -----------------------------------------------------------

def test_negative_nominal_model_factors_are_refused_per_row():
    from arvcas.sim.run import SimulationError, _nonnegative_factors

    _nonnegative_factors(np.array([0.0, 1.0, 1.2, 0.5]))
    with pytest.raises(SimulationError, match=r"^uncertainty: factor D is -0.1; the nominal-model factors "
                                              r"\[C, D, g, arm\] are >= 0$"):
        _nonnegative_factors(np.array([1.0, -0.1, 1.0, 1.0]))
    with pytest.raises(SimulationError, match=r"^uncertainty: row 2, factor arm is -2;"):
        _nonnegative_factors(np.array([[1.0] * 4, [1.0] * 4, [1.0, 1.0, 1.0, -2.0]]))


# ---- gain tables -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("value, shown", [("true", r"True \(bool\)"), ('"2.55"', r"'2.55' \(str\)"),
                                          ("[2.55]", r"\[2.55\] \(list\)"), ("{ a = 1 }", r"\{'a': 1\} \(dict\)"),
                                          ("nan", r"nan; expected a finite number > 0"),
                                          ("-inf", r"-inf; expected a finite number > 0"),
                                          ("-2.0", r"-2.0; expected a finite number > 0"),
                                          ("0", r"0; expected a finite number > 0")])
def test_a_gain_table_with_anything_but_positive_finite_numbers_is_refused(tmp_path, value, shown):
    from arvcas.controllers import gains
    from arvcas.system import shipped

    src = shipped()["bluerov2_heavy_alpha5"].parent
    text = (src / "bluerov2_heavy_alpha5.gains.toml").read_text()
    old = "y = [1.5830, 0.0023,"
    assert old in text
    table = tmp_path / "g.toml"
    table.write_text(text.replace(old, f"y = [{value}, 0.0023,", 1))
    system = (src / "bluerov2_heavy_alpha5.toml").read_text()
    system = re.sub(r'^gains = ".*"$', f'gains = "{table}"', system, flags=re.M)
    system = re.sub(r'^scenario = "(.*)"$', lambda m: f'scenario = "{src / m.group(1)}"', system, flags=re.M)
    system = system.replace('table = "t200_16v.csv"', f'table = "{src / "t200_16v.csv"}"')
    (tmp_path / "s.toml").write_text(system)
    gains._TABLES.clear()
    tail = "" if "expected" in shown else "; expected a number"
    with pytest.raises(gains.GainError, match=rf"g.toml: \[agsta\].y: c is {shown}{tail}$"):
        gains.default_gains("agsta", str(tmp_path / "s.toml"))


# ---- events, tasks and waypoints after the run's end ---------------------------------------------------

def _trajectory(*times):
    out = '\n[trajectory]\npattern = "waypoints"\nsegment = "minimum_jerk"\n'
    for t in times:
        out += (f'[[trajectory.waypoint]]\nt = {{ value = {t}, unit = "s", source = "test" }}\n'
                f'eta = {{ value = [0, 0, 0, 0, 0, 0], unit = "m,m,m,rad,rad,rad", source = "test" }}\n')
    return out


def _warned(path) -> list[str]:
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        load_scenario(path)
    return [str(x.message) for x in w if issubclass(x.category, ScenarioWarning)]


def test_a_waypoint_whose_motion_ends_after_the_run_is_warned_with_its_time(tmp_path):
    p = scenario_variant(tmp_path, "duration = { value = 60.0,", "duration = { value = 30.0,")
    msgs = _warned(p)
    assert any(re.search(r"arm.waypoint\[4\].t: 37 s is after the run's end \(time.duration 30 s\): this waypoint "
                         r"is never reached$", m) for m in msgs), msgs


@pytest.mark.parametrize("times, want", [
    ((70, 80), r"trajectory.waypoint\[1\].t: 70 s: the task starts at or after the run's end, so it runs nothing "
               r"\(time.duration 60 s\)"),
    ((10, 75), r"trajectory.waypoint\[2\].t: 75 s is after the run's end \(time.duration 60 s\): this waypoint is "
               r"never reached"),
])
def test_a_task_after_the_run_is_warned_with_its_time_and_the_runs_length(tmp_path, times, want):
    p = tmp_path / "task.toml"
    base = scenario_variant(tmp_path, "duration = { value = 60.0,", "duration = { value = 60.0,", "b.toml")
    p.write_text(base.read_text() + _trajectory(*times))
    msgs = _warned(p)
    assert any(re.search(want, m) for m in msgs), msgs
    assert all(str(p) in m for m in msgs)  # each names the file


def test_a_task_within_the_run_warns_nothing(tmp_path):
    p = tmp_path / "task.toml"
    base = scenario_variant(tmp_path, "duration = { value = 60.0,", "duration = { value = 60.0,", "b.toml")
    p.write_text(base.read_text() + _trajectory(5, 40))
    assert not [m for m in _warned(p) if "trajectory" in m]
