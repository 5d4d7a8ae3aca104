"""Parameter file: loading, ordering, immutability, and one-line errors naming the file and the key.

Every bad file is the packaged ``haidou1.toml`` with one edit, written to ``tmp_path``.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from arvcas.system import params as ap
from arvcas.system.params import ParamsError


@pytest.fixture(scope="module")
def text():
    return ap.default_path().read_text(encoding="utf-8")


def _write(tmp_path, content, name="bad.toml"):
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content, encoding="utf-8")
    return path


def _sub1(text, old, new):
    """Replace exactly one occurrence (the edit must hit the intended line)."""
    assert text.count(old) == 1, f"edit target not unique: {old!r}"
    return text.replace(old, new)


def _load_error(path) -> str:
    with pytest.raises(ParamsError) as ei:
        ap.load(path)
    msg = str(ei.value)
    assert "\n" not in msg, f"error is not one line: {msg!r}"
    assert str(path) in msg, f"error does not name the file: {msg!r}"
    return msg


# --- the good file -------------------------------------------------------------------------------


def test_load_default(params):
    assert isinstance(params, ap.Params)
    names = params.names()
    for n in ("env.rho", "env.g", "env.Cd"):
        assert n in names
    assert len(names) == len(set(names)) == len(params)
    assert np.all(np.isfinite(params.vector()))
    # a few values, converted to SI by the loader (mm -> m, deg -> rad)
    assert params["env.rho"] == 1027.77
    assert params["env.g"] == 9.8
    assert params["env.Cd"] == 1.0
    assert params["arm.joint2.a"] == pytest.approx(0.1304, rel=1e-15)
    assert params["arm.joint5.alpha"] == pytest.approx(-math.pi / 2, rel=1e-15)
    assert params["thrusters.u_min"] == -146.9 and params["thrusters.u_max"] == 231.6


def test_vector_order_is_names(params):
    vec = params.vector()
    names = params.names()
    assert vec.shape == (len(names),)
    for i, n in enumerate(names):
        assert vec[i] == params[n], n
    assert list(params.as_dict()) == names
    # view() of the vector reads the same numbers by name
    v = ap.view(vec)
    assert all(v[n] == params[n] for n in names)


def test_replace_returns_new_and_keeps_old(params):
    old_vec = params.vector().copy()
    new = params.replace({"env.rho": 0.0, "payload.mass": 4.5})
    assert isinstance(new, ap.Params) and new is not params
    assert new["env.rho"] == 0.0 and new["payload.mass"] == 4.5
    assert params["env.rho"] == 1027.77 and params["payload.mass"] == 3.0
    np.testing.assert_array_equal(params.vector(), old_vec)
    changed = np.flatnonzero(new.vector() != old_vec)
    assert sorted(params.names()[i] for i in changed) == ["env.rho", "payload.mass"]
    with pytest.raises(ParamsError, match=r"env\.rho"):
        params.replace({"env.rhoo": 1.0})
    with pytest.raises(ParamsError, match=r"vehicle\.m"):
        params.replace({"vehicle.m": -1.0})
    with pytest.raises(ParamsError, match=r"env\.g"):
        params.replace({"env.g": float("nan")})


# --- bad files ------------------------------------------------------------------------------------


def test_missing_file(tmp_path):
    _load_error(tmp_path / "does_not_exist.toml")


def test_malformed_toml(tmp_path, text):
    # drop the closing brace of env.rho (line 10 of the packaged file)
    bad = _sub1(text, 'rho = { value = 1027.77, unit = "kg/m^3", source = "Table A1" }',
                'rho = { value = 1027.77, unit = "kg/m^3", source = "Table A1"')
    lineno = text.splitlines().index(
        'rho = { value = 1027.77, unit = "kg/m^3", source = "Table A1" }') + 1
    msg = _load_error(_write(tmp_path, bad))
    assert "malformed" in msg.lower()
    # TOML's parser cannot name a key in a broken line; it names the line, which is the key's line
    assert re.search(rf"line {lineno}\b", msg), msg


def test_non_utf8(tmp_path, text):
    raw = _sub1(text, 'source = "Table A1: B = (m + 2) g"', 'source = "Table A1: B = (m + 2) g \xb0"')
    _load_error(_write(tmp_path, raw.encode("latin-1")))


def test_unknown_key_with_suggestion(tmp_path, text):
    bad = _sub1(text, 'Cd = { value = 1.0,', 'Cdd = { value = 1.0, unit = "1", source = "typo" }\nCd = { value = 1.0,')
    msg = _load_error(_write(tmp_path, bad))
    assert "env.Cdd" in msg and "did you mean 'env.Cd'" in msg, msg


def test_missing_key(tmp_path, text):
    lines = [ln for ln in text.splitlines() if not ln.startswith("Ixz = ")]
    assert len(lines) == len(text.splitlines()) - 1
    msg = _load_error(_write(tmp_path, "\n".join(lines) + "\n"))
    assert "missing" in msg and "vehicle.Ixz" in msg, msg


@pytest.mark.parametrize("bad_value", ["nan", "inf", "-inf"])
def test_non_finite_value(tmp_path, text, bad_value):
    bad = _sub1(text, "Iyy = { value = 4036.0,", f"Iyy = {{ value = {bad_value},")
    msg = _load_error(_write(tmp_path, bad))
    assert "vehicle.Iyy" in msg and "finite" in msg, msg


def test_wrong_unit(tmp_path, text):
    bad = _sub1(text, 'm = { value = 4325.925, unit = "kg",', 'm = { value = 4325.925, unit = "m",')
    msg = _load_error(_write(tmp_path, bad))
    assert "vehicle.m" in msg and "unit" in msg, msg


def test_negative_mass(tmp_path, text):
    # link 1 is the first [arm.linkN] table; its mass line is the first "mass = { value = 10.0"
    assert text.count("mass = { value = 10.0,") == 1
    bad = text.replace("mass = { value = 10.0,", "mass = { value = -10.0,")
    msg = _load_error(_write(tmp_path, bad))
    assert "arm.link1.mass" in msg and "-10" in msg, msg
