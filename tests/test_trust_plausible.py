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
    files = shipped()
    assert sorted(files) == sorted(SHIPPED), "a shipped system's file is missing from the package"
    with warnings.catch_warnings():
        warnings.simplefilter("error", PlausibilityWarning)
        for name in SHIPPED:
            load(files[name])


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


# ---- thrust limits against the vehicle's weight (systems without a command map: instantaneous thrusters) ----

def _shipped_variant(tmp_path, name: str, key: str, value: str, accept: bool = False):
    """A shipped system file without thruster maps, copied to ``tmp_path`` with every ``key`` line (the
    thrusters' ``u_min`` or ``u_max``) given ``value``; its relative files named by absolute path."""
    src = shipped()[name]
    text, n = re.subn(rf"^{key} = \{{ value = [^,]+,", f"{key} = {{ value = {value},", src.read_text(), flags=re.M)
    assert n >= 1 and "[thrusters.map" not in text, (name, key)
    for rel in ("scenario.toml", "gains.toml"):
        text = text.replace(f'"{rel}"', f'"{src.parent / rel}"')
    if accept:
        text = text.replace("[system]\n", "[system]\naccept_implausible = true\n", 1)
    p = tmp_path / f"{name}_{key}_{value.replace('-', 'm')}{'_ok' if accept else ''}.toml"
    p.write_text(text)
    return p


# (system, its thrust-limit key as the loader names it, the vehicle's weight m g in N as the message prints it)
THRUST_SYSTEMS = [("haidou1", "thrusters.u_max", "4.239e+04"),  # Haidou-1's parametric layout: one pair of limits
                  ("hinsdale_bluerov2_alpha5", "thrusters.T1.u_max", "143")]  # a thruster list: T1 is named first


@pytest.mark.parametrize("name, key, weight", THRUST_SYSTEMS)
def test_thrust_limits_against_the_weight(tmp_path, name, key, weight):
    """docs/system-file.md, Plausibility: |u_min|, |u_max| / (m g) above 10 is warned, above 1000 refused in
    one line naming the key, and ``accept_implausible = true`` loads it deliberately (as a warning)."""
    W = load(shipped()[name])
    mg = W["vehicle.m"] * W["env.g"]
    assert f"{mg:.4g}" == weight
    leaf = key.rsplit(".", 1)[-1]
    # within the rule: 9 times the weight loads without a warning (the limit is the file's, unchanged rule)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PlausibilityWarning)
        P = load(_shipped_variant(tmp_path, name, leaf, f"{9 * mg:.6g}"))
    assert P[key] == pytest.approx(9 * mg, rel=1e-5)
    # implausible: 20 times the weight is warned (once per limit of the file) and loads
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        P = load(_shipped_variant(tmp_path, name, leaf, f"{20 * mg:.6g}"))
    msgs = [str(w.message) for w in rec if issubclass(w.category, PlausibilityWarning)]
    assert any(f"{key}: {20 * mg:g} N against the vehicle's weight {weight} N (20 times), more than 10 times" in m
               for m in msgs), msgs
    # one warning per edited limit, nothing else judged implausible
    assert len(msgs) == sum(k.endswith(f".{leaf}") for k in P.layout.names), msgs
    assert all(f".{leaf}: " in m and "N against the vehicle's weight" in m for m in msgs), msgs
    assert P[key] == pytest.approx(20 * mg, rel=1e-5)
    # impossible: 2000 times the weight is refused, one line naming the key and the flag
    with pytest.raises(ParamsError) as e:
        load(_shipped_variant(tmp_path, name, leaf, f"{2000 * mg:.6g}"))
    msg = str(e.value)
    assert "\n" not in msg and f"{key}: " in msg and "more than 1000 times is not a vehicle" in msg, msg
    assert "accept_implausible = true" in msg, msg
    # a reverse limit of the same size: the rule takes |u_min|
    with pytest.raises(ParamsError, match=rf"{re.escape(key[:-3])}min: -?[\d.e+]+ N against the vehicle's weight"):
        load(_shipped_variant(tmp_path, name, "u_min", f"{-2000 * mg:.6g}"))
    # deliberately: accepted, warned as what it is
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        P = load(_shipped_variant(tmp_path, name, leaf, f"{2000 * mg:.6g}", accept=True))
    msgs = [str(w.message) for w in rec if issubclass(w.category, PlausibilityWarning)]
    assert any(f"{key}: " in m and "more than 1000 times is not a vehicle" in m for m in msgs), msgs
    assert P[key] == pytest.approx(2000 * mg, rel=1e-5)


def test_thrust_limit_refused_and_warned_by_the_command_line(tmp_path, capsys):
    """The same rule through the CLI: the impossible limit is one line (exit 2, nothing written), the
    implausible one a single warning line."""
    from arvcas import cli

    H = load(shipped()["haidou1"])
    mg = H["vehicle.m"] * H["env.g"]
    bad = _shipped_variant(tmp_path, "haidou1", "u_max", f"{2000 * mg:.6g}")
    assert_refused(["simulate", "--controller", "pid", "--system", bad], capsys, tmp_path,
                   "thrusters.u_max: ")
    odd = _shipped_variant(tmp_path, "haidou1", "u_max", f"{20 * mg:.6g}")
    assert cli.main(["systems"]) == 0
    capsys.readouterr()
    assert cli.main(["demo", "--system", str(odd)]) == 0
    err = capsys.readouterr().err
    assert err.count("arvcas: warning: ") == 1 and "thrusters.u_max: " in err and "more than 10 times" in err, err
