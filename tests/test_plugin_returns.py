"""A law's code returns what the closed loop needs, or the command stops in one line: whatever a law's
``initial`` or ``step`` returns (None, a string, a vector of the wrong length, a state of the wrong width)
or raises is one :class:`ControllerError` naming the law's file, the method, what came back and what was
expected, while the graph is built (before any compile), for every law: a plugin file on the command
line, a class of the user's own code, and (property) any value a step can return."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import arvcas
from arvcas import cli
from arvcas.controllers import base
from arvcas.sim import closedloop, scenario

from trust_helpers import bad_law

# (what the step does, words of the one line it must give)
CASES = {
    "none": ("return None", ["step returned NoneType None", "expected a pair (tau_v, next_state)"]),
    "string": ('return "tau"', ["step returned str 'tau'", "expected a pair"]),
    "short": ("return [0.0] * 5, x", ["step returned list [0.0, 0.0, 0.0, 0.0, 0.0] as tau_v", "a 6-vector"]),
    "matrix": ("return ca.repmat(tau, 1, 2), x", ["SX of shape (6, 2) as tau_v", "a 6-vector"]),
    "raises": ("return tau / 0 if 1 / 0 else tau", ["step raised ZeroDivisionError: division by zero",
                                                   "line 17)"]),
    "state": ("return tau, {}", ["step returned no state entry 'w'", "w (6)"]),
    "width": ('return tau, {"w": x["w"][0:3]}', ["step returned SX of shape (3, 1) for the state entry 'w'",
                                                  "a 6-vector"]),
    "statetype": ("return tau, None", ["step returned NoneType None as its state", "a dict"]),
    "nan": ("return ca.DM([float('nan')] * 6), x", ["step returned DM of shape (6, 1) with non-finite values as "
                                                    "tau_v", "6 finite numbers"]),
    "constinf": ("return ca.SX.ones(6) * float('inf'), x", ["SX of shape (6, 1) with non-finite values as tau_v"]),
    "stateinf": ('return tau, {"w": ca.DM.ones(6) * float("inf")}', ["DM of shape (6, 1) with non-finite values for "
                                                                     "the state entry 'w'"]),
}


@pytest.mark.parametrize("tag", list(CASES))
def test_a_plugin_law_that_returns_the_wrong_thing_is_one_line_before_any_compile(tag, fresh, tmp_path, capsys,
                                                                                  monkeypatch):
    monkeypatch.setenv("ARVCAS_CACHE", str(tmp_path / "cache"))
    body, words = CASES[tag]
    law = tmp_path / f"toy_bad_{tag}.py"
    law.write_text(bad_law(f"toy_bad_{tag}", step=body, block="toy_bad"))
    rc = cli.main(["simulate", "--plugin", str(law), "--controller", f"toy_bad_{tag}",
                   "--out", str(tmp_path / "r.h5")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and err.startswith("arvcas: error: "), err
    assert f"controller 'toy_bad_{tag}' (plugin file {law})" in err, err  # which plugin, which file
    for w in words:
        assert w in err, (w, err)
    assert not (tmp_path / "r.h5").exists()
    assert not any((tmp_path / "cache").rglob("*.so")) if (tmp_path / "cache").exists() else True  # nothing built


class _Returns(arvcas.Controller):
    """A law of the user's own code whose step returns ``value`` (set per example)."""

    name = "returns"
    gains = (arvcas.Gain("k", "1/s", "gain"),)
    defaults_block = "returns"
    state = (("w", 2),)
    value = None

    def initial(self, ctx, G):
        return {"w": [0.0, 0.0]}

    def step(self, ctx, G, x):
        return self.value


_numbers = st.floats(allow_nan=True, allow_infinity=True, width=64)
_vectors = st.lists(_numbers, min_size=0, max_size=8)
_leaves = st.none() | st.booleans() | st.text(max_size=5) | _numbers | _vectors | \
    st.builds(lambda v: ca.DM(v) if v else ca.DM(0, 1), _vectors) | \
    st.builds(ca.DM, st.lists(_numbers, min_size=6, max_size=6)) | st.builds(ca.DM, st.lists(_numbers, min_size=2, max_size=2))
_states = st.dictionaries(st.sampled_from(["w", "v"]), _leaves, max_size=2) | _leaves
_returns = st.tuples(_leaves, _states) | _leaves | st.tuples(_leaves) | st.tuples(_leaves, _states, _leaves)


@settings(max_examples=300, deadline=None)
@given(_returns)
def test_any_step_return_is_accepted_as_the_right_shapes_or_refused_in_one_line(value):
    law = _Returns()
    law.value = value
    try:
        tau, x = base.call_law(law, "step", None, {}, {"w": ca.DM.zeros(2)})
    except base.ControllerError as e:
        msg = str(e)
        assert "\n" not in msg and msg.startswith("controller 'returns' (") and "step returned" in msg
        assert "expected" in msg
        return
    # accepted: a 6-vector and the law's state of its declared width, finite where numeric
    assert tau.shape == (6, 1) and x["w"].shape == (2, 1)
    for v in (tau, x["w"]):
        if isinstance(v, ca.DM):
            assert np.all(np.isfinite(np.asarray(v)))
    assert isinstance(value, tuple) and len(value) == 2 and isinstance(value[1], dict)


def test_every_built_in_law_passes_the_checks_unchanged():
    """The checks accept every law of the package as it is (their graph is built through them), on the first
    shipped system the law runs on (a law may refuse a system, e.g. ArduSub's needs its eight-thruster frame)."""
    from arvcas.system.loader import SHIPPED

    for name in base.names():
        built = []
        for sysname in SHIPPED:
            s = arvcas.load_system(sysname)
            cfg = scenario.load_scenario(s.params.default("scenario"))
            try:
                fns = closedloop.controller_functions(name, cfg, s.params.layout)
            except base.ControllerError:
                continue
            built.append(sysname)
            assert fns["step"].size_out("u")[0] > 0
            break
        assert built, f"{name}: no shipped system takes it"


def test_initial_is_checked_as_well():
    class Init(_Returns):
        def initial(self, ctx, G):
            return {"w": "zero"}

    with pytest.raises(base.ControllerError, match=r"initial returned str 'zero' for the state entry 'w'; "
                                                   r"expected a 2-vector"):
        base.call_law(Init(), "initial", None, {})


# ---- objectives of the user's own: what values and elements return ------------------------------------------

@settings(max_examples=200, deadline=None)
@given(st.none() | st.text(max_size=4) | st.booleans() | _numbers | st.lists(_numbers, max_size=5) |
       st.lists(st.lists(_numbers, min_size=1, max_size=3), min_size=1, max_size=4))
def test_any_objective_return_is_an_array_of_its_shape_or_one_line(value):
    from arvcas.metrics import objectives

    class Mine(objectives.Objective):
        name, unit = "mine", "1"

        def values(self, out, ctx):
            return value

    n = 3
    for method in ("values", "elements"):
        try:
            a = objectives.call_objective(Mine(), method, {"ok": np.ones(n)}, None, n)
        except objectives.ObjectiveError as e:
            msg = str(e)
            assert "\n" not in msg and msg.startswith(f"objective 'mine' (") and f": {method} " in msg, msg
            continue
        assert a.shape == (n,) if method == "values" else (a.ndim == 2 and a.shape[0] == n)


def test_an_objective_that_raises_names_its_file_and_line():
    from arvcas.metrics import objectives

    class Broken(objectives.Objective):
        name, unit = "broken", "1"

        def values(self, out, ctx):
            return out["no such output"]

    with pytest.raises(objectives.ObjectiveError, match=r"^objective 'broken' \(.*test_plugin_returns.py\): values "
                                                        r"raised KeyError: 'no such output' \(test_plugin_returns.py, "
                                                        r"line \d+\)$"):
        objectives.call_objective(Broken(), "values", {"ok": np.ones(2)}, None, 2)
