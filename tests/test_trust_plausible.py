"""Physical and scenario plausibility, stated as rules (docs/system-file.md, Plausibility): damping must
dissipate; masses, volumes, distances and thrust limits are checked against the vehicle's own scale; the
impossible is refused in one line, the implausible warned, ``[system] accept_implausible = true`` accepts
deliberately; the shipped systems pass without a warning. Scenarios: no event after the run ends,
set-point angles wrapped, a pitch at +-90 deg refused."""

from __future__ import annotations

import math
import re
import warnings

import pytest

from arvcas.system.params import ParamsError, PlausibilityWarning, load
from arvcas.sim.scenario import ScenarioError, load_scenario
from arvcas.system import SHIPPED, shipped

from trust_helpers import assert_refused, scenario_variant

BLUE = shipped()["bluerov2_heavy_alpha5"]


def _variant(tmp_path, *subs, accept: bool = False):
    """The shipped BlueROV2 with ``(pattern, replacement)`` substitutions (the first match of each)."""
    text = BLUE.read_text()
    for pat, new in subs:
        text, n = re.subn(pat, new, text, count=1, flags=re.M)
        assert n == 1, pat
    if accept:
        text = text.replace("[system]\n", "[system]\naccept_implausible = true\n", 1)
    p = tmp_path / f"v{len(list(tmp_path.glob('v*.toml')))}.toml"
    p.write_text(text.replace('"bluerov2_heavy_alpha5.', f'"{BLUE.parent}/bluerov2_heavy_alpha5.'))
    return p


def _value(key: str, v: str):
    return rf"^{key} = \{{ value = [^,]+,", f"{key} = {{ value = {v},"


def test_the_shipped_systems_pass_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error", PlausibilityWarning)
        for name in SHIPPED + ("hinsdale_bluerov2_alpha5",):
            if name in shipped():
                load(shipped()[name])


@pytest.mark.parametrize("sub, message", [
    (_value("X_u", "500.0"), "the linear damping injects energy"),
    (_value("Y_v_absv", "217.0"), "injects energy at every speed of v"),
    (_value("mass", "1e12"), "1e+12 kg against the vehicle's 13.5 kg"),
    (_value("volume", "1.34e4"), "buoyancy 9.93e+05 times the weight"),
    (_value("volume", "1.34e-5"), "buoyancy 0.000993 times the weight"),
    ((r"^position = \{ value = \[0.156, 0.111, 0.085\]", "position = { value = [1.0e6, 0.111, 0.085]"),
     "thrusters.T1.position.x: 1e+06 m against the vehicle's size 0.238 m"),
    # with the T200s' command map, a thrust limit beyond the map's range is refused by the map's own rule
    # first (docs/system-file.md); the plausibility rule on thrust limits covers systems without a map
    (_value("u_max", "1e30"), "1e+30 N needs a command outside the range of its map t200_16v"),
])
def test_the_impossible_is_refused_in_one_line(tmp_path, sub, message):
    with pytest.raises(ParamsError) as e:
        load(_variant(tmp_path, sub))
    msg = str(e.value)
    assert message in msg and ("accept_implausible" in msg or "its map" in message) and "\n" not in msg, msg


def test_the_implausible_is_warned_and_the_impossible_accepted_deliberately(tmp_path):
    with pytest.warns(PlausibilityWarning, match=r"arm.link1.mass: 20 kg against the vehicle's 13.5 kg \(1.48 times\)"):
        load(_variant(tmp_path, _value("mass", "20.0")))
    with pytest.warns(PlausibilityWarning, match="is not a vehicle"):
        P = load(_variant(tmp_path, _value("mass", "1e12"), accept=True))
    assert P["arm.link1.mass"] == 1e12
    with pytest.raises(ParamsError, match="system.accept_implausible: expected true or false"):
        load(_variant(tmp_path, (r"^\[system\]$", '[system]\naccept_implausible = "yes"')))


def test_the_command_line_refuses_and_warns_in_one_line(tmp_path, capsys):
    bad = _variant(tmp_path, _value("X_u", "500.0"))
    assert_refused(["simulate", "--controller", "pid", "--system", bad], capsys, tmp_path, "injects energy")
    from arvcas import cli

    odd = _variant(tmp_path, _value("mass", "20.0"))
    assert cli.main(["systems"]) == 0 and cli.main(["demo", "--system", str(odd)]) == 0
    err = capsys.readouterr().err
    assert err.count("arvcas: warning: ") == 1 and "arm.link1.mass: 20 kg" in err and "Warning" not in err, err


def test_scenario_rules(tmp_path):
    from arvcas.sim.scenario import ScenarioWarning

    with pytest.warns(ScenarioWarning, match=r"payload.event\[1\].t: 70 s: this event starts at or after the run's "
                                             r"end \(time.duration 60 s\), so it changes nothing"):
        load_scenario(scenario_variant(tmp_path, 't = { value = 20.0, unit = "s"', 't = { value = 70.0, unit = "s"'))
    with pytest.warns(ScenarioWarning, match=r"arm.waypoint\[4\].t: .* starts at or after the run's end"):
        load_scenario(scenario_variant(tmp_path, 'duration = { value = 60.0,', 'duration = { value = 22.0,', "s2.toml"))
    line = 'eta_d = { value = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0], unit = "m,rad",'
    for new, want in (('eta_d = { value = [0.0, 0.0, 0.0, 0.0, 0.0, 720.0], unit = "m,m,m,deg,deg,deg",', 0.0),
                      ('eta_d = { value = [0.0, 0.0, 0.0, 0.0, 0.0, -190.0], unit = "m,m,m,deg,deg,deg",', 170.0)):
        c = load_scenario(scenario_variant(tmp_path, line, new))  # 720 deg asked the vehicle for two turns
        assert math.isclose(math.degrees(c.initial_eta_d[5]), want, abs_tol=1e-9), c.initial_eta_d
    with pytest.raises(ScenarioError, match=r"initial.eta_d: pitch 95 deg is at or beyond \+-90 deg"):
        load_scenario(scenario_variant(tmp_path, line, 'eta_d = { value = [0.0, 0.0, 0.0, 0.0, 95.0, 0.0], unit = "m,m,m,deg,deg,deg",'))
