"""`arvcas params --system S`: every parameter name with its SI value, unit and source, the names
`arvcas identify --free` takes; and the docs name parameters that exist."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import arvcas
from arvcas import cli
from arvcas.system import shipped

DOCS = Path(__file__).resolve().parent.parent / "docs"


def _rows(text: str) -> dict[str, tuple[float, str, str]]:
    out = {}
    for line in text.splitlines():
        if line.startswith("#"):
            continue
        m = re.fullmatch(r"(\S+)\s+(\S+)\s+(\S+)\s+(.*)", line)
        assert m, line
        out[m.group(1)] = (float(m.group(2)), m.group(3), m.group(4))
    return out


@pytest.mark.parametrize("name", list(shipped()))
def test_params_lists_every_parameter(name, capsys):
    assert cli.main(["params", "--system", name]) == 0
    out = capsys.readouterr().out
    rows = _rows(out)
    P = arvcas.load_system(name).params
    assert list(rows) == P.names()  # every name, in the parameter vector's order
    assert out.splitlines()[0].startswith(f"# {len(P)} of {len(P)} parameters of {name}")
    for n, (value, unit, source) in rows.items():
        assert value == pytest.approx(P[n], rel=1e-7, abs=1e-12), n
        assert source == P.source(n) and source, n


def test_params_units_are_si(capsys):
    assert cli.main(["params", "--system", "bluerov2_heavy_alpha5", "--match", "arm.joint1."]) == 0
    rows = _rows(capsys.readouterr().out)
    assert rows["arm.joint1.qmax"][1] == "rad" and rows["arm.joint1.z"][1] == "m"
    assert rows["arm.joint1.yaw"][0] == 0.0
    assert cli.main(["params", "--system", "bluerov2_heavy_alpha5", "--match", "arm.joint3.yaw"]) == 0
    rows = _rows(capsys.readouterr().out)  # written 180 deg in the file: listed in SI
    assert rows["arm.joint3.yaw"] == (pytest.approx(3.14159265), "rad", rows["arm.joint3.yaw"][2])
    assert cli.main(["params", "--system", "bluerov2", "--match", "hydro.X_u_absu"]) == 0
    rows = _rows(capsys.readouterr().out)
    assert rows["hydro.X_u_absu"][:2] == (-141.0, "kg/m")


def test_params_names_are_what_identify_takes(capsys, tmp_path):
    """Every listed name is accepted by identify's --free check; a wrong one is refused with the closest."""
    from arvcas.experiments.validation import _names

    assert cli.main(["params", "--system", "bluerov2", "--match", "thrusters.T1.position"]) == 0
    names = list(_rows(capsys.readouterr().out))
    assert names == ["thrusters.T1.position.x", "thrusters.T1.position.y", "thrusters.T1.position.z"]
    assert _names(",".join(names)) == tuple(names)
    rc = cli.main(["identify", "--system", "bluerov2", "--free", "thrusters.T1.z", str(tmp_path / "x.log.toml"),
                   "--out", str(tmp_path / "o.toml")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1, err
    assert ("--free: bluerov2 has no parameter 'thrusters.T1.z' (did you mean 'thrusters.T1.position.z' or "
            "'thrusters.T1.direction.z'?)") in err
    assert "`arvcas params --system bluerov2` lists them" in err


def test_params_match_nothing_is_one_line(capsys):
    assert cli.main(["params", "--system", "haidou1", "--match", "hydro.X_uu_q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--match: no parameter of haidou1 contains 'hydro.X_uu_q'" in err


def test_docs_name_parameters_that_exist():
    """A parameter name written in docs/ (``env.``, ``vehicle.``, ``hydro.``, ``thrusters.``, ``arm.``,
    ``payload.`` followed by a dotted name) is a parameter of a shipped system, or a section of one (or a
    Python module path, a scenario key)."""
    names = set()
    for n in shipped():
        names |= set(arvcas.load_system(n).params.names())
    prefixes = {".".join(n.split(".")[:k]) for n in names for k in range(1, n.count(".") + 1)}
    allowed = {  # not parameters: module paths, file sections and scenario keys the docs name on purpose
        "thrusters.lag_states", "thrusters.envelope", "thrusters.map_thrust", "thrusters.unit", "thrusters.map.basic",
        "thrusters.map.rexrov", "thrusters.unactuated", "hydro.coriolis_added_mass", "hydro.gauss_legendre",
        "hydro.planar_drag", "vehicle.D", "arm.jointN", "arm.linkN", "arm.urdf", "arm.lock", "arm.trim", "arm.base",
        "arm.waypoint", "arm.hold_until", "arm.return_start", "arm.payload_on", "payload.event",
    }
    bad = []
    for f in sorted(DOCS.rglob("*.md")):
        text = f.read_text(encoding="utf-8")
        for m in re.finditer(r"(?<![\w/.])((?:env|vehicle|hydro|thrusters|arm|payload)\.[A-Za-z0-9_.<>]+)", text):
            x = m.group(1).rstrip(".")
            if "<" in x:  # a pattern (arm.joint<i>, thrusters.map.<name>)
                continue
            if x not in names and x not in prefixes and x not in allowed:
                bad.append(f"{f.relative_to(DOCS)}:{text[:m.start()].count(chr(10)) + 1}: {x}")
    assert not bad, bad
