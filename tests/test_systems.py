"""Systems described as data. The shipped systems' vehicles, allocation and envelopes, the
system file's refusals, scenarios as data, and the BlueROV2's closed loop.

The multibody cross-checks against Pinocchio (random URDF arms, Haidou-1 DH vs URDF) are in
tests/test_system_pinocchio.py; Haidou-1's committed results against this code in test_paper.py and
test_tuning_front.py.
"""

from __future__ import annotations

import re

import casadi as ca
import numpy as np
import pytest

import arvcas
from arvcas.model import thrusters, vehicle
from arvcas.system.params import ParamsError, view
from arvcas.sim import limits, profiles, scenario
from arvcas.system import shipped

SYSTEMS = ("haidou1", "bluerov2_heavy_alpha5", "hinsdale_bluerov2_alpha5", "bluerov2", "bluerov2_heavy")
FULLY_ACTUATED = tuple(n for n in SYSTEMS if n != "bluerov2")  # bluerov2 has no pitch: tests/test_armless.py


@pytest.fixture(scope="module")
def systems():
    return {n: arvcas.load_system(n) for n in SYSTEMS}


def _np(x):
    return np.array(ca.evalf(x) if isinstance(x, (ca.SX, ca.MX)) else x, dtype=float)


def test_shipped_list_and_api(systems):
    assert tuple(shipped()) == SYSTEMS
    h, b = systems["haidou1"], systems["bluerov2_heavy_alpha5"]
    assert (h.name, h.n_thrusters, h.n_joints, h.structure.arm) == ("haidou1", 6, 6, "dh")
    assert (b.name, b.n_thrusters, b.n_joints, b.structure.arm) == ("bluerov2_heavy_alpha5", 8, 4, "chain")
    assert "8 thrusters" in repr(b) and b.params.default("scenario").name == "bluerov2_heavy_alpha5.scenario.toml"
    assert arvcas.load_system(str(b.path)).params == b.params  # by path: the same numbers
    with pytest.raises(ParamsError, match="neither a shipped system .*did you mean 'bluerov2_heavy_alpha5'"):
        arvcas.load_system("bluerov2_heavy_alpha")


@pytest.mark.parametrize("name", SYSTEMS)
def test_every_number_has_a_source_inside_the_repository(systems, name):
    p = systems[name].params
    for n in p.names():
        src = p.source(n)
        assert src.strip(), n
        assert "../shared" not in src and "SPEC" not in src, (n, src)


@pytest.mark.parametrize("name", SYSTEMS)
def test_vehicle_properties(systems, name):
    """M positive definite, nu' C(nu) nu = 0 (C_RB and C_A skew in the sense of Fossen), and at rest
    level the restoring force is the net weight in heave only, with no moment where CG is above/below CB."""
    P = view(systems[name].params)
    M = _np(vehicle.M(P))
    assert np.linalg.eigvalsh(0.5 * (M + M.T))[0] > 0
    rng = np.random.default_rng(3)
    for _ in range(20):
        nu = rng.normal(size=6)
        C = _np(vehicle.C_RB(P, ca.DM(nu)))
        assert abs(nu @ C @ nu) <= 1e-12 * np.linalg.norm(C) * (nu @ nu)
        if systems[name].structure.coriolis_added_mass:
            CA = _np(vehicle.C_A(P, ca.DM(nu)))
            assert abs(nu @ CA @ nu) <= 1e-12 * np.linalg.norm(CA) * (nu @ nu)
    g0 = _np(vehicle.g_vec(P, ca.DM.zeros(6))).ravel()
    W, B = (float(x) for x in vehicle.weight_buoyancy(P))
    np.testing.assert_allclose(g0[:3], [0, 0, -(W - B)], atol=1e-12 * W)
    if name != "hinsdale_bluerov2_alpha5":  # ballasted with its arm, level only with it (tests/test_hinsdale.py)
        np.testing.assert_allclose(g0[3:], 0, atol=1e-12 * W)


def test_parametric_allocation_is_the_thruster_list_form_of_its_geometry(systems):
    """The parametric layout (Appendix B, Haidou-1's) gives the matrix a thruster list gives for the same
    positions and directions, column [d; r x d]: computed here by NumPy's cross product on the file's
    numbers, bit for bit. (The parametric form is kept: its stern angles are parameters, and its hydrodynamic
    terms in ds need them.)"""
    h = systems["haidou1"]
    assert h.structure.thrusters is None
    g = h.params
    B = _np(thrusters.B_T(view(g.vector(), h.layout)))
    k = {n: g[f"thrusters.{n}"] for n in ("delta_sL", "delta_sR", "x_stn", "y_stn", "z_stn", "x_bow", "y_bow",
                                           "x_hB", "x_hS")}
    pos = [(k["x_stn"], -k["y_stn"], k["z_stn"]), (k["x_stn"], k["y_stn"], k["z_stn"]), (k["x_hB"], 0, 0),
           (k["x_hS"], 0, 0), (k["x_bow"], -k["y_bow"], 0), (k["x_bow"], k["y_bow"], 0)]
    dirs = [(np.cos(k["delta_sL"]), 0, -np.sin(k["delta_sL"])), (np.cos(k["delta_sR"]), 0, -np.sin(k["delta_sR"])),
            (0, 1, 0), (0, 1, 0), (0, 0, 1), (0, 0, 1)]
    ref = np.array([np.r_[d, np.cross(r, d)] for r, d in zip(pos, dirs)]).T
    assert (B == ref).all()
    assert h.structure.thruster_names()[0] == "T1 stern left"


def test_bluerov2_damping_is_diagonal_linear_plus_quadratic(systems):
    """The SNAME names give the usual ROV damping: D(nu) nu = -diag(X_u + X_u|u| |u|, ...) nu."""
    b = systems["bluerov2_heavy_alpha5"]
    P = view(b.params)
    nu = np.array([0.3, -0.2, 0.1, 0.4, -0.5, 0.6])
    Dnu = (_np(vehicle.D(P, ca.DM(nu))) @ nu).ravel()
    lin = np.array([b.params.as_dict().get(f"hydro.{F}_{v}", 0.0) for F, v in zip("XYZKMN", "uvwpqr")])
    quad = np.array([b.params.as_dict().get(f"hydro.{F}_{v}_abs{v}", 0.0) for F, v in zip("XYZKMN", "uvwpqr")])
    np.testing.assert_allclose(Dnu, -(lin + quad * np.abs(nu)) * nu, rtol=1e-14)
    assert quad.min() < 0 and (lin <= 0).all()


@pytest.mark.parametrize("name", FULLY_ACTUATED)
def test_allocation_reproduces_wrenches_inside_the_envelope(systems, name):
    """thrust(allocate(tau)) = tau for every wrench whose allocation stays within the limits; the
    pure-axis capacity is the largest such wrench along each axis (min-norm allocation is linear)."""
    s = systems[name]
    p = s.params.vector()
    al, th = arvcas.compiled("allocate", system=s), arvcas.compiled("thrust", system=s)
    P = view(s.params)
    lo, hi = (np.broadcast_to(_np(x).ravel(), (s.n_thrusters,)) for x in thrusters.limits(P))
    Bm = _np(thrusters.B_T(P))
    A = np.linalg.pinv(Bm) if s.n_thrusters > 6 else np.linalg.inv(Bm)
    rng = np.random.default_rng(11)
    n_in = 0
    for _ in range(200):
        tau = rng.normal(size=6) * np.abs(Bm).sum(axis=1) * 0.2
        u = np.array(al(tau, p)).ravel()
        np.testing.assert_allclose(u, A @ tau, rtol=1e-10, atol=1e-9 * np.abs(tau).max())
        if (u >= lo).all() and (u <= hi).all():
            n_in += 1
            np.testing.assert_allclose(np.array(th(u, p)).ravel(), tau, rtol=1e-10, atol=1e-10 * np.abs(tau).max())
    assert n_in > 20
    for k in range(6):  # the capacity along axis k: saturation starts exactly there
        a = A[:, k]
        cap = min(np.where(a > 0, hi / np.where(a > 0, a, 1), np.inf).min(),
                  np.where(a < 0, lo / np.where(a < 0, a, 1), np.inf).min())
        e = np.eye(6)[k]
        u = np.array(al(cap * e, p)).ravel()
        assert (u >= lo - 1e-9).all() and (u <= hi + 1e-9).all()
        assert np.isclose(u, hi).any() or np.isclose(u, lo).any()
        np.testing.assert_allclose(np.array(th(u, p)).ravel(), cap * e, atol=1e-9 * cap)
        over = np.array(th(np.array(al(1.01 * cap * e, p)).ravel(), p)).ravel()
        assert not np.allclose(over, 1.01 * cap * e, atol=1e-6 * cap)  # beyond it a thruster saturates


def test_bluerov2_envelope_numbers(systems):
    """The pure-axis capacities of the BlueROV2 Heavy at +-30.4 N (docs/systems/bluerov2_heavy_alpha5.md)."""
    s = systems["bluerov2_heavy_alpha5"]
    lo, hi = thrusters.envelope(view(s.params))
    np.testing.assert_allclose(hi, [85.98, 85.98, 121.6, 26.51, 14.59, 22.96], rtol=2e-3)
    np.testing.assert_allclose(lo, hi, rtol=1e-12)  # symmetric limits, symmetric layout


# ---- the system file's refusals ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def btext():
    return shipped()["bluerov2_heavy_alpha5"].read_text(encoding="utf-8")


def _edit(text: str, old: str, new: str) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


def _section(text: str, table: str, old: str, new: str) -> str:
    a = text.index(f"[{table}]\n")
    b = text.find("\n[", a + 1)
    b = len(text) if b < 0 else b
    assert text[a:b].count(old) == 1, (table, old)
    return text[:a] + text[a:b].replace(old, new) + text[b:]


def _thruster(text: str, name: str, old: str, new: str) -> str:
    a = text.index(f'name = "{name}"')
    b = text.index("[[thrusters.unit]]", a) if "[[thrusters.unit]]" in text[a:] else len(text)
    return text[:a] + text[a:b].replace(old, new, 1) + text[b:]


BAD = [
    ("unknown derivative name", lambda t: _edit(t, "X_udot = {", "X_udott = {"),
     r"hydro.X_udott: .*did you mean 'X_udot'"),
    ("a factor that is no factor", lambda t: _edit(t, "X_udot = {", "X_ux = {"), r"hydro.X_ux: .*unknown factor 'ux'"),
    ("minimum thrust above maximum", lambda t: _thruster(t, "T3", "value = -30.4,", "value = 40.0,"),
     r"thrusters.T3.u_min, thrusters.T3.u_max: u_min \(40 N\) must be < u_max"),
    ("thruster layout of rank < 6", lambda t: re.sub(r"direction = \{ value = \[[^\]]*\]", "direction = { value = [0.0, 0.0, -1.0]", t),
     r"rank [0-5], not 6"),
    ("direction not a unit vector", lambda t: _thruster(t, "T1", "direction = { value = [", "direction = { value = [2.0, "),
     r"thrusters.T1.direction|must be a list of 3"),
    ("rigid-body inertia not positive definite", lambda t: _edit(t, "Ixx = { value = 0.26,", "Ixx = { value = -0.26,"),
     r"vehicle.Ixx: value must be > 0"),
    ("M_RB + M_A not invertible", lambda t: _edit(t, "X_udot = { value = -6.36,", "X_udot = { value = 13.5,"),
     r"hydro.X_udot: the inertia M = M_RB \+ M_A is not positive definite in DOF 1"),
    ("zero-length link with drag", lambda t: _edit(t, 'drag_to = { value = [-0.02, 0.0, 0.033], unit = "m"',
                                                   'drag_to = { value = [0.0, 0.0, 0.0], unit = "m"'),
     r"arm.link1.drag_from, arm.link1.drag_to: link 1's drag segment has zero length"),
    ("link inertia not positive definite", lambda t: _section(t, "arm.link2", "inertia = { value = [7.945437e-04,", "inertia = { value = [-1e-3,"),
     r"arm.link2.inertia: link 2's inertia tensor is not positive definite"),
    ("joint axis not a unit vector", lambda t: _edit(t, "axis = { value = [0.0, 0.0, 1.0]", "axis = { value = [0.0, 0.0, 2.0]"),
     r"arm.joint1.axis: the joint axis must be a unit vector"),
    ("more than 7 joints", None, r"at most 7"),
    ("two forms of buoyancy", lambda t: t.replace("[vehicle]\n", '[vehicle]\nbuoyancy_excess = { value = 0.0, unit = "kg", source = "x" }\n', 1),
     r"vehicle: give exactly one of 'buoyancy_excess'"),
    ("arm.trim not a boolean", lambda t: t + "\n[arm]\ntrim = 1\n", r"arm.trim: expected true or false, got 1"),
]


@pytest.mark.parametrize("label,edit,pattern", BAD, ids=[b[0] for b in BAD])
def test_bad_system_file_is_refused_in_one_line(tmp_path, btext, label, edit, pattern):
    text = btext
    if edit is None:  # 8 joints: joint and link tables 5..8 copied from 4
        j4 = re.search(r"\[arm.joint4\]\n(.*?)(?=\n\[)", text, re.S).group(1)
        l4 = re.search(r"\[arm.link4\]\n(.*?)(?=\n\[|\Z)", text, re.S).group(1)
        extra = "".join(f"\n[arm.joint{i}]\n{j4}\n\n[arm.link{i}]\n{l4}\n" for i in range(5, 9))
        text = text + extra
    else:
        text = edit(text)
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ParamsError) as ei:
        arvcas.load_system(path)
    msg = str(ei.value)
    assert "\n" not in msg and str(path) in msg
    assert re.search(pattern, msg), msg


# ---- scenarios as data ---------------------------------------------------------------------------------


PAPER_AS_WAYPOINTS = """
[[arm.waypoint]]
t = { value = 5.0, unit = "s", source = "the paper's hold_until" }
q = "stow"
[[arm.waypoint]]
t = { value = 20.0, unit = "s", source = "reach_end" }
q = { value = [60.0, 60.0, -60.0, 0.0, 60.0, 0.0], unit = "deg", source = "qg" }
[[arm.waypoint]]
t = { value = 25.0, unit = "s", source = "return_start" }
q = { value = [60.0, 60.0, -60.0, 0.0, 60.0, 0.0], unit = "deg", source = "qg" }
[[arm.waypoint]]
t = { value = 40.0, unit = "s", source = "return_end" }
q = "stow"
"""


def _paper_waypoint_text():
    text = scenario.default_scenario_path().read_text(encoding="utf-8")
    a = text.index("[arm]")
    b = text.index("\n[", a + 1)
    events = ('\n[payload]\n[[payload.event]]\nt = { value = 22.0, unit = "s", source = "payload_on" }\n'
              'ramp = { value = 0.5, unit = "s", source = "payload_ramp" }\nto = { value = 1.0, unit = "1", source = "x" }\n')
    return text[:a] + "[arm]\n" + PAPER_AS_WAYPOINTS + text[b:] + events


def test_arm_trim_off_removes_exactly_the_trim(tmp_path, btext):
    """``[arm] trim = false`` (a vehicle whose numbers include its ballast, docs/system-file.md): uvms_rhs
    and the closed loop's run constants carry no trim, and nothing else changes. With the trim (the shipped
    BlueROV2, CG above CB) the vehicle at rest, level, arm stowed, has almost no angular acceleration."""
    from arvcas.model import manipulator, uvms
    from arvcas.sim import closedloop

    path = tmp_path / "notrim.toml"
    path.write_text(btext + "\n[arm]\ntrim = false\n", encoding="utf-8")
    on, off = arvcas.load_system("bluerov2_heavy_alpha5"), arvcas.load_system(path)
    assert on.structure.arm_trim and not off.structure.arm_trim
    assert np.array_equal(on.params.vector(), off.params.vector())
    P_on, P_off = view(on.params), view(off.params)
    opts = uvms.ModelOptions()
    x = ca.DM.zeros(12)
    q0 = manipulator.stow_pose(P_on)
    z4 = ca.DM.zeros(4)
    xd_on = _np(uvms.uvms_xdot(P_on, x, ca.DM.zeros(6), q0, z4, z4, 0, opts)).ravel()
    xd_off = _np(uvms.uvms_xdot(P_off, x, ca.DM.zeros(6), q0, z4, z4, 0, opts)).ravel()
    xd_none = _np(uvms.uvms_xdot(P_on, x, ca.DM.zeros(6), q0, z4, z4, 0, opts, trim=ca.DM.zeros(6))).ravel()
    np.testing.assert_allclose(xd_off, xd_none, rtol=1e-14, atol=1e-15)
    # trimmed, only the net weight's coupling through the arm's inertia remains; untrimmed, the arm's moment
    assert np.abs(xd_on[9:12]).max() < 0.01 * np.abs(xd_off[9:12]).max()
    np.testing.assert_array_equal(_np(manipulator.trim_wrench(P_off, ca.DM.zeros(6))).ravel(), 0)
    assert np.all(_np(closedloop.derived_constants(P_off, opts))[:3] == 0)
    assert np.all(_np(closedloop.derived_constants(P_on, opts))[:3] != 0)


def test_paper_scenario_as_waypoints_equals_its_reach_form(params):
    """The paper's reach-and-return is one waypoint scenario: q, qd, qdd and the payload agree to 1e-15."""
    a = scenario.load_scenario()
    b = scenario.loads_scenario(_paper_waypoint_text(), "waypoints")
    assert b.arm_qg is None and len(b.arm_waypoint) == 4 and len(b.payload_event) == 1
    limits.check_joint_limits(b, params)
    P = view(params)
    from arvcas.model.manipulator import stow_pose

    q0 = stow_pose(P)
    t = ca.SX.sym("t")
    fa = ca.Function("a", [t], [*profiles.joint_trajectory(a, q0, t), profiles.payload_profile(a, t)])
    fb = ca.Function("b", [t], [*profiles.joint_trajectory(b, q0, t), profiles.payload_profile(b, t)])
    for tt in np.linspace(0, 60, 1201):
        for x, y in zip(fa(tt), fb(tt)):
            np.testing.assert_allclose(np.array(y), np.array(x), rtol=0, atol=1e-15 * max(1.0, float(np.abs(np.asarray(x, dtype=float)).max())))
    back = scenario.loads_scenario(b.to_toml(), "effective")
    assert back.graph_key() == b.graph_key()


@pytest.mark.parametrize("edit,pattern", [
    (lambda t: t.replace('t = { value = 20.0, unit = "s", source = "reach_end" }',
                         't = { value = 4.0, unit = "s", source = "reach_end" }'),
     r"arm.waypoint\[2\].t: 4 s must be after waypoint 1's 5 s"),
    (lambda t: t.replace("[arm]\n", '[arm]\nqg = { value = [0, 0, 0, 0, 0, 0], unit = "deg", source = "x" }\n'),
     r"arm.qg: not with \[\[arm.waypoint\]\]"),
])
def test_bad_waypoints_are_refused(edit, pattern):
    with pytest.raises(scenario.ScenarioError, match=pattern):
        scenario.loads_scenario(edit(_paper_waypoint_text()), "waypoints")


def test_waypoints_outside_the_limits_or_of_the_wrong_size_are_refused(params, systems):
    b = scenario.loads_scenario(_paper_waypoint_text().replace("[60.0, 60.0, -60.0, 0.0, 60.0, 0.0]",
                                                               "[60.0, 60.0, -60.0, 0.0, 120.0, 0.0]", 1), "w")
    with pytest.raises(scenario.ScenarioError, match=r"arm.waypoint\[2\].q: joint 5 target 120.00 deg outside"):
        limits.check_joint_limits(b, params)
    with pytest.raises(scenario.ScenarioError, match=r"6 joint angles, but system 'bluerov2_heavy_alpha5' has 4"):
        arvcas.Run("pid", scenario=scenario.loads_scenario(_paper_waypoint_text(), "w"),
                   system="bluerov2_heavy_alpha5").compile()


# ---- the BlueROV2 closed loop ---------------------------------------------------------------------------


def test_bluerov2_run_compiled_equals_vm_and_signals_are_sized(systems):
    """A short BlueROV2 run: the generated C equals CasADi's VM on the same graph; the trace has a thrust
    column per thruster and a joint column per joint; CHAT/RMSE from the trace equal the accumulators."""
    from dataclasses import replace

    from arvcas import metrics
    from arvcas.sim import closedloop

    s = systems["bluerov2_heavy_alpha5"]
    cfg = scenario.load_scenario(s.params.default("scenario"))
    cfg = replace(cfg, time_duration=20.0)
    run = arvcas.Run("proposed", scenario=cfg, system=s).compile()
    r = run.simulate(seed=1)
    assert r.ok and r.thrust.shape == (201, 8) and r.q.shape == (201, 4)
    np.testing.assert_allclose(metrics.chat(r.tau_cmd), r.chat, rtol=1e-12)
    q_reach = r.q[-1]
    assert np.abs(q_reach - [s.params[f"arm.stow.q{i}"] for i in range(1, 5)]).max() > 0.1  # the arm moved
    vm = closedloop.build_run(closedloop.RunSpec(run.controller, cfg.graph_key(), run.opts, s.layout), trace=False)
    ins = {"gains": run.default_gains(), "noise": profiles.noise_sequence(cfg, 1), "unc": cfg.uncertainty,
           "phase": np.array(cfg.disturbance_phase), **run._shared()}
    out = vm.call({k: ca.DM(v) for k, v in ins.items()})
    np.testing.assert_allclose(np.array(out["chat"]).ravel(), r.chat, rtol=1e-12)
    np.testing.assert_allclose(np.array(out["rmse"]).ravel(), r.rmse, rtol=1e-12)
