"""Physical validity of parameter files: each check refuses a packaged ``haidou1.toml``
with one edit, written to ``tmp_path``, with a one-line :class:`ParamsError` naming the file and key."""

from __future__ import annotations

import pytest

from arvcas.system import params as ap
from arvcas.system.params import ParamsError


@pytest.fixture(scope="module")
def text():
    return ap.default_path().read_text(encoding="utf-8")


def _edit(text: str, table: str, old: str, new: str) -> str:
    """Replace ``old`` by ``new`` once, inside ``[table]`` (the edit must hit the intended line)."""
    head = f"[{table}]\n"
    assert text.count(head) == 1, table
    a = text.index(head)
    b = text.find("\n[", a + len(head))
    b = len(text) if b < 0 else b
    section = text[a:b]
    assert section.count(old) == 1, f"edit target not unique in [{table}]: {old!r}"
    return text[:a] + section.replace(old, new) + text[b:]


CASES = [
    # (label, table, old, new, key the message must name, fragment of the message)
    ("inertia not positive definite", "vehicle", "Ixz = { value = 38.0,", "Ixz = { value = 3800.0,",
     "vehicle.Ixz", "not positive definite"),
    ("principal moments break the triangle inequality", "vehicle", "Ixx = { value = 999.0,", "Ixx = { value = 9999.0,",
     "vehicle.Ixx", "triangle inequality"),
    ("rigid-body mass matrix not positive definite", "vehicle", "zG = { value = 0.05,", "zG = { value = 2.0,",
     "vehicle.zG", "M_RB is not positive definite"),
    ("added mass makes M indefinite", "hydro", "X_udot = { value = -1.419,", "X_udot = { value = 10.0,",
     "hydro.X_udot", "M = M_RB + M_A"),
    ("added mass makes M indefinite in yaw", "hydro", "N_rdot = { value = -5.087,", "N_rdot = { value = 5.087,",
     "hydro.N_rdot", "DOF 6"),
    ("thrust limits not ordered", "thrusters", "u_min = { value = -146.9,", "u_min = { value = 231.6,",
     "thrusters.u_min", "must be < u_max"),
    ("joint limits not ordered", "arm.joint2", "qmin = { value = -30.0,", "qmin = { value = 90.0,",
     "arm.joint2.qmin", "must be < qmax"),
    ("stowed pose outside its limits", "arm.stow", "q3 = { value = -90.0,", "q3 = { value = -100.0,",
     "arm.stow.q3", "outside joint 3's limits"),
    ("thruster layout of rank 5", "thrusters", "x_hS = { value = -1.0,", "x_hS = { value = 0.8,",
     "thrusters.x_hS", "rank 5, not 6"),
    ("zero-length link 4 with drag", "arm.joint5", "a = { value = 21.5,", "a = { value = 0.0,",
     "arm.joint5.a", "link 4 has zero length"),
    ("zero-length link 6 (the tool)", "arm.tool", "length = { value = 0.20,", "length = { value = 0.0,",
     "arm.tool.length", "link 6 has zero length"),
]


@pytest.mark.parametrize("label,table,old,new,key,fragment", CASES, ids=[c[0] for c in CASES])
def test_unphysical_file_is_refused(tmp_path, text, label, table, old, new, key, fragment):
    path = tmp_path / "bad.toml"
    path.write_text(_edit(text, table, old, new), encoding="utf-8")
    with pytest.raises(ParamsError) as ei:
        ap.load(path)
    msg = str(ei.value)
    assert "\n" not in msg, f"error is not one line: {msg!r}"
    assert msg.startswith(f"{path}: "), msg
    assert key in msg and fragment in msg, msg


def test_rotatable_thrusters_both_vertical_is_really_rank_deficient(text, tmp_path):
    """The second rank case is a real degeneracy: with delta_sL = delta_sR = -90 deg the two stern thrusters
    push only along z, so nothing produces surge (the message names the singular values)."""
    bad = _edit(text, "thrusters", "delta_sR = { value = -55.0,", "delta_sR = { value = -90.0,")
    bad = _edit(bad, "thrusters", "delta_sL = { value = -72.0,", "delta_sL = { value = -90.0,")
    path = tmp_path / "vertical.toml"
    path.write_text(bad, encoding="utf-8")
    with pytest.raises(ParamsError, match=r"rank [0-5], not 6"):
        ap.load(path)


def test_packaged_file_is_physical(params):
    ap.check_physical(params.as_dict(), "packaged")  # no exception
    # the checks see the model's matrices: the packaged M is positive definite with margin
    import numpy as np
    from arvcas.model import vehicle

    M = np.array(vehicle.M(ap.view(params.vector())), dtype=float)
    assert np.linalg.eigvalsh(0.5 * (M + M.T))[0] > 1000.0


def test_boundary_values_are_physical(tmp_path, text):
    """Limits that touch (a stowed angle equal to its joint limit) and rho = 0 (no added mass) pass."""
    ok = _edit(text, "env", "rho = { value = 1027.77,", "rho = { value = 0.0,")
    path = tmp_path / "ok.toml"
    path.write_text(ok, encoding="utf-8")
    P = ap.load(path)
    assert P["env.rho"] == 0.0 and P["arm.stow.q3"] == P["arm.joint3.qmin"]
