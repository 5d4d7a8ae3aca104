"""Vehicle trajectories (docs/tasks.md): the generators against independent references, the scenario's
refusals, and tasks in the closed loop (a trajectory is an input: no recompile; RMSE against eta_d(t_k);
a built-in and a user's controller track it with the arm's motion on top).

The references: the polynomial's boundary values by numpy.polynomial (not the module's own evaluation),
Flash & Hogan's closed form written out here, the minimum-jerk optimality condition (the jerk is
orthogonal to the third derivative of every admissible variation) by SciPy's quadrature, a lawnmower's
corners by hand.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial import polynomial as npoly
from scipy.integrate import quad

import arvcas
from arvcas.sim import limits, scenario, schedule, trajectory as tj
from arvcas.sim.scenario import ScenarioError


# ---- the generators ------------------------------------------------------------------------------------

def test_quintic_meets_its_six_boundary_conditions():
    rng = np.random.default_rng(7)
    for _ in range(20):
        T = rng.uniform(0.5, 30)
        p0, v0, a0, p1, v1, a1 = rng.normal(size=(6, 6))
        C = tj.quintic_coefficients(T, p0, v0, a0, p1, v1, a1)
        for d in range(6):
            c = C[:, d]
            got = [npoly.polyval(x, npoly.polyder(c, k)) for k in range(3) for x in (0.0, T)]
            want = [p0[d], p1[d], v0[d], v1[d], a0[d], a1[d]]
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * (1 + abs(p1[d] - p0[d])))


def test_minimum_jerk_is_flash_hogan():
    """Flash & Hogan (1985), eq. for a rest-to-rest move: x0 + (xf - x0)(10 s^3 - 15 s^4 + 6 s^5), s = t / T."""
    p0, p1 = np.array([1, -2, 0.5, 0.1, -0.2, 1.0]), np.array([4, 1, 2.5, -0.1, 0.3, -1.0])
    tr = tj.from_waypoints([3.0, 11.0], [p0, p1], "minimum_jerk")
    t = np.linspace(0, 14, 281)
    s = np.clip((t - 3) / 8, 0, 1)[:, None]
    want_p = p0 + (p1 - p0) * (10 * s**3 - 15 * s**4 + 6 * s**5)
    want_v = (p1 - p0) * 30 * s**2 * (1 - s) ** 2 / 8
    p, v, a = tr.sample(t)
    np.testing.assert_allclose(p, want_p, atol=1e-12)
    np.testing.assert_allclose(v, want_v, atol=1e-12)
    # the peak speed of the closed form: 1.875 (xf - x0) / T at the middle
    np.testing.assert_allclose(tr.sample([7.0])[1][0], 1.875 * (p1 - p0) / 8, rtol=1e-12)
    np.testing.assert_allclose(tj.min_jerk(p0, p1, 3.0, 11.0, t)[0], want_p, atol=1e-12)


def test_minimum_jerk_is_optimal():
    """The integral of jerk^2 is stationary (so, being convex, minimal) against every variation that keeps
    position, velocity and acceleration at both ends: int x''' d''' dt = 0 for d = s^3 (1-s)^3 s^j."""
    T = 6.0
    tr = tj.from_waypoints([0.0, T], [np.zeros(6), np.ones(6)], "minimum_jerk")
    jerk = lambda t: 6 * tr.coeffs[0, 3, 0] + 24 * tr.coeffs[0, 4, 0] * t + 60 * tr.coeffs[0, 5, 0] * t**2  # noqa: E731
    norm = quad(lambda t: jerk(t) ** 2, 0, T)[0]
    for j in range(3):
        d = npoly.polymul(npoly.polypow([0, 1 / T], 3 + j), npoly.polypow([1, -1 / T], 3))  # s^(3+j) (1 - s)^3
        d3 = npoly.polyder(d, 3)
        inner = quad(lambda t: jerk(t) * npoly.polyval(t, d3), 0, T)[0]
        d_norm = quad(lambda t: npoly.polyval(t, d3) ** 2, 0, T)[0]
        assert abs(inner) < 1e-9 * np.sqrt(norm * d_norm)
    # and a quintic through the same ends with nonzero end accelerations has more jerk
    other = tj.quintic_coefficients(T, np.zeros(1), np.zeros(1), np.ones(1), np.ones(1), np.zeros(1), np.zeros(1))
    j2 = lambda t: 6 * other[3, 0] + 24 * other[4, 0] * t + 60 * other[5, 0] * t**2  # noqa: E731
    assert quad(lambda t: j2(t) ** 2, 0, T)[0] > norm


def test_quintic_passes_waypoints_with_their_rates():
    t = [0.0, 4.0, 10.0, 12.0]
    P = np.array([[0, 0, 0, 0, 0, 0], [2, 1, 0, 0, 0, 0.5], [2, 3, 1, 0, 0, 1.0], [0, 3, 1, 0, 0, 1.0]], float)
    tr = tj.from_waypoints(t, P, "quintic")
    p, v, a = tr.sample(t)
    np.testing.assert_allclose(p, P, atol=1e-12)
    want_v = np.zeros_like(P)
    want_v[1] = (P[2] - P[0]) / 10.0  # central difference at the inner waypoints
    want_v[2] = (P[3] - P[1]) / 8.0
    np.testing.assert_allclose(v, want_v, atol=1e-12)
    np.testing.assert_allclose(a, 0, atol=1e-12)
    # continuous rate across an inner waypoint, held after the last
    pl, vl, _ = tr.sample([4.0 - 1e-7, 4.0 + 1e-7])
    np.testing.assert_allclose(vl[0], vl[1], atol=1e-5)
    np.testing.assert_allclose(tr.sample([20.0])[0][0], P[-1])
    np.testing.assert_allclose(tr.sample([-1.0])[0][0], P[0])


@pytest.mark.parametrize("heading", [0.0, np.pi / 2])
def test_lawnmower_corners(heading):
    start = np.array([1.0, 2.0, 5.0, 0.0, 0.0, 0.3])
    t, P = tj.lawnmower(start, 4.0, 3, 10.0, 2.0, 0.5, heading)
    a = np.array([np.cos(heading), np.sin(heading)])
    b = np.array([-np.sin(heading), np.cos(heading)])  # starboard of the heading (NED: x north, y east)
    xy = start[:2]
    want = [xy, xy + 10 * a, xy + 10 * a + 2 * b, xy + 2 * b, xy + 4 * b, xy + 10 * a + 4 * b]
    np.testing.assert_allclose(P[:, :2], want, atol=1e-12)
    np.testing.assert_allclose(P[:, 2:], np.tile(start[2:], (6, 1)))
    np.testing.assert_allclose(t, [4, 24, 28, 48, 52, 72])


# ---- the scenario: loading, refusals ---------------------------------------------------------------------

BASE = open(scenario.default_scenario_path()).read().replace(
    'duration = { value = 100.0, unit = "s"', 'duration = { value = 20.0, unit = "s"')
APPROACH = '''
[trajectory]
pattern = "approach"
target = { value = [0.2, 0.05, 0.05, 0, 0, 0.03], unit = "m,m,m,rad,rad,rad", source = "test" }
start = { value = 2.0, unit = "s", source = "test" }
duration = { value = 14.0, unit = "s", source = "test" }
'''


def task(text: str = APPROACH) -> scenario.ScenarioConfig:
    return scenario.loads_scenario(BASE + text, "task.toml")


def waypoints(*rows, extra="", segment="minimum_jerk"):
    out = f'\n[trajectory]\npattern = "waypoints"\nsegment = "{segment}"\n'
    for t, eta in rows:
        out += f'[[trajectory.waypoint]]\nt = {{ value = {t}, unit = "s", source = "test" }}\n'
        out += f'eta = {{ value = {list(eta)}, unit = "m,m,m,rad,rad,rad", source = "test" }}\n'
    return out + extra


def test_a_task_round_trips_and_only_its_presence_keys_the_graph():
    cfg = task()
    assert cfg.has_trajectory and not scenario.load_scenario().has_trajectory
    back = scenario.loads_scenario(cfg.to_toml())
    assert back.trajectory_values() == cfg.trajectory_values()
    other = task(APPROACH.replace("[0.2, 0.05, 0.05", "[-0.1, 0.0, 0.1"))
    assert other.graph_key() == cfg.graph_key() and other.trajectory_values() != cfg.trajectory_values()
    tr = cfg.trajectory()  # approach from the set point initial.eta_d
    np.testing.assert_allclose(tr.points, [cfg.initial_eta_d, [0.2, 0.05, 0.05, 0, 0, 0.03]])
    np.testing.assert_allclose(tr.times, [2.0, 16.0])


@pytest.mark.parametrize("text, match", [
    (waypoints((0, [0] * 6), (5, [1, 0, 0, 0, 0, 0]), (5, [2, 0, 0, 0, 0, 0])),
     r"task.toml: trajectory.waypoint\[3\].t: 5 s must be after waypoint 2's 5 s"),
    (APPROACH.replace('start =', 'legs = { value = 2, unit = "1", source = "x" }\nstart ='),
     r"trajectory.legs: not a key of pattern 'approach' \(its keys: target, duration, start\)"),
    (APPROACH.replace("target =", "targt ="), r"unknown key 'trajectory.targt'.*did you mean"),
    (APPROACH.replace('"approach"', '"spiral"'), r"trajectory.pattern.*spiral.*waypoints, lawnmower, approach"),
    (APPROACH.replace("duration =", "# duration ="), r"trajectory.duration: missing: pattern 'approach' needs"),
    (waypoints((0, [0] * 6), (5, [1, 0, 0, 0, 0, 0]),
               extra='rate = { value = [0.1, 0, 0, 0, 0, 0], unit = "m/s,rad/s", source = "x" }\n'),
     r"trajectory.waypoint\[2\].rate: a waypoint's rate goes with segment = \"quintic\""),
    (waypoints((0, [0] * 6), (5, [1, 0, 0, 0, 1.6, 0])), r"trajectory.waypoint\[2\].eta: pitch 91.67\d* deg is at or beyond"),
])
def test_bad_trajectories_are_one_line(text, match):
    with pytest.raises(ScenarioError, match=match) as e:
        task(text)
    assert "\n" not in str(e.value)


def test_a_trajectory_beyond_the_thrusters_is_refused_before_any_work():
    params = arvcas.load_system("haidou1").params
    fast = task(waypoints((1, [0] * 6), (3, [20, 0, 0, 0, 0, 0])))
    with pytest.raises(ScenarioError, match=r"task.toml: trajectory.waypoint\[2\].t: the trajectory asks thruster "
                                            r"\S+ for \d+ % of its limit at t = [\d.]+ s \(segment 1 of 1"):
        limits.check_trajectory_limits(fast, params)
    with pytest.raises(ScenarioError, match="waypoint"):
        arvcas.Run("pid", scenario=fast, system=params).compile()
    limits.check_trajectory_limits(task(), params)  # the 0.21 m approach in 14 s


# ---- tasks in the closed loop ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def pid_task():
    cfg = task()
    run = arvcas.Run("pid", scenario=cfg).compile()
    return cfg, run, run.simulate(seed=1)


def test_the_time_table_carries_the_desired_trajectory(pid_task):
    cfg, run, _ = pid_task
    tab = run.table
    ns_ts = schedule.n_stages(cfg) * schedule.records().time_size
    assert tab.time.shape[0] == ns_ts + 12
    t = np.arange(scenario.n_samples(cfg)) * cfg.time_h
    s = np.clip((t - 2.0) / 14.0, 0, 1)
    target = np.array([0.2, 0.05, 0.05, 0, 0, 0.03])
    np.testing.assert_allclose(tab.time[ns_ts:ns_ts + 6].T, np.outer(10 * s**3 - 15 * s**4 + 6 * s**5, target),
                               atol=1e-13)
    np.testing.assert_allclose(tab.time[ns_ts + 6:].T, np.outer(30 * s**2 * (1 - s) ** 2 / 14.0, target), atol=1e-13)


def test_rmse_is_against_the_desired_trajectory_and_the_reference_joins_it(pid_task):
    cfg, run, r = pid_task
    assert r.ok
    eta_d = cfg.trajectory().sample(r.t)[0]
    e = r.eta[:-1] - eta_d[:-1]  # eq. 43 over k = 0..N-1, against eta_d(t_k)
    np.testing.assert_allclose(r.rmse, np.sqrt((e**2).mean(axis=0)), rtol=1e-12)
    late = r.t > 3 * cfg.atd_T  # the ATD has taken the start's offset to zero
    assert np.abs(r.eta_ref[late] - eta_d[late]).max() < 1e-6
    assert np.abs(r.eta_ref[0] - r.eta_hat[0]).max() == 0  # and started from the estimate
    # the vehicle followed: a 0.21 m move within 2 cm once the start's 3 cm offset is gone, the arm moving meanwhile (the paper's reach at 5 s)
    assert np.abs(e[late[:-1], :3]).max() < 0.02 and r.q[-1, 0] != r.q[0, 0]


def test_a_new_trajectory_is_a_new_input_not_a_new_library(pid_task):
    cfg, run, r = pid_task
    other = arvcas.Run("pid", scenario=task(APPROACH.replace("[0.2, 0.05, 0.05", "[-0.1, 0.1, 0.0"))).compile()
    assert other.function(True) is run.function(True)
    r2 = other.simulate(seed=1)
    assert r2.ok and np.abs(r2.eta[-1, :3] - [-0.1, 0.1, 0.0]).max() < 0.02
    assert np.abs(r.eta[-1, :3] - [0.2, 0.05, 0.05]).max() < 0.02


def test_station_keeping_is_a_trajectory_that_holds_its_set_point(pid_task):
    """A 'task' that holds eta_d follows the station-keeping reference to round-off (y1 = eta_d + z1 against
    the ATD driven to eta_d directly: the same recursion, fhan(y1 - eta_d, y2) = fhan(z1, z2))."""
    sk = scenario.loads_scenario(BASE, "sk.toml")
    hold = task(waypoints((0, sk.initial_eta_d), (1, sk.initial_eta_d)))
    a = arvcas.Run("pid", scenario=hold).compile().simulate(seed=1)
    b = arvcas.Run("pid", scenario=sk).compile().simulate(seed=1)
    np.testing.assert_allclose(a.eta_ref, b.eta_ref, atol=1e-12)
    np.testing.assert_allclose(a.eta, b.eta, atol=1e-9)


class _ToyPD(arvcas.Controller):
    """A user's law (the registry's path, as a plugin's): PD on the reference error in {n}."""

    name = "toy_task_pd"
    gains = (arvcas.Gain("kp", "1/s^2", "proportional"), arvcas.Gain("kd", "1/s", "derivative"))
    defaults = [0.6, 1.6] * 6
    defaults_block = "toy"

    def initial(self, ctx, G):
        return {}

    def step(self, ctx, G, x):
        from arvcas.model.spatial import J
        import casadi as ca

        return ca.mtimes(J(ctx.eta_hat).T, ctx.Mhat * (-G["kp"] * ctx.e - G["kd"] * ctx.e_dot)), {}


def test_a_users_controller_tracks_the_task():
    c = arvcas.register_controller(_ToyPD(), replace=True)
    try:
        cfg = task()
        chat, rmse, ok, _ = arvcas.Run(c.name, scenario=cfg).compile().batch(
            np.array([[0.6, 1.6] * 6, [1.2, 2.4] * 6]), seed=0, return_status=True)
        assert ok.all() and (rmse[:, :3] < 0.02).all()
        assert (rmse[1] < rmse[0])[:3].all()  # the stiffer PD follows the move more closely
    finally:
        arvcas.controllers.unregister(c.name)


def test_export_controller_refuses_a_task():
    from arvcas.sim import closedloop

    with pytest.raises(ValueError, match=r"export-controller: the scenario has a \[trajectory\]"):
        closedloop.controller_functions("pid", task(), arvcas.load_system("haidou1").params.layout)


# ---- a user's controller from a --plugin file on a task, through the command line ----------------------------

CLI_LAW = '''\
"""A lab's law (a test's plugin): PD on the reference error in {n}, with its own signal."""
import casadi as ca

import arvcas
from arvcas.model.spatial import J
from arvcas.sim.signals import DOFS, Signal


class LabTaskPD(arvcas.Controller):
    name = "lab_task_pd"
    description = "tau_eta = -Mhat (kp e + kd e_dot)"
    gains = (arvcas.Gain("kp", "1/s^2", "proportional"), arvcas.Gain("kd", "1/s", "derivative"))
    defaults = [0.6, 1.6] * 6
    defaults_block = "lab_task_pd"
    signals = (Signal("e_seen", 6, "m,m,m,rad,rad,rad", "{n}", DOFS, "the error the law sees",
                      lambda c: c.out["e"]),)

    def initial(self, ctx, G):
        return {}

    def step(self, ctx, G, x):
        ctx.out["e"] = ctx.e
        return ca.mtimes(J(ctx.eta_hat).T, ctx.Mhat * (-G["kp"] * ctx.e - G["kd"] * ctx.e_dot)), {}
'''


def test_a_plugin_controller_tracks_a_task_from_the_command_line(tmp_path, capsys, fresh):
    """``arvcas simulate --plugin toy_task_law.py --controller lab_task_pd --config task.toml`` (a scenario
    with a [trajectory]): it runs, its RMSE is against eta_d(t_k) (eq. 43 on the written trace), equals the
    Python API's run of the same law, scenario and seed bit for bit, and is what the command printed."""
    from arvcas import cli
    from arvcas.io.results import read_result

    law = tmp_path / "toy_task_law.py"
    law.write_text(CLI_LAW)
    scen = tmp_path / "task.toml"
    scen.write_text(BASE + APPROACH)
    out = tmp_path / "r.h5"
    rc = cli.main(["simulate", "--plugin", str(law), "--controller", "lab_task_pd", "--config", str(scen),
                   "--seed", "1", "--out", str(out)])
    text, err = capsys.readouterr()
    assert rc == 0, err
    assert text.startswith("lab_task_pd: seed 1, 20 s, ok"), text
    r = read_result(out)
    assert r.ok and r.controller == "lab_task_pd" and r.meta["controller_source"]["kind"] == "file"
    cfg = scenario.load_scenario(scen)
    assert cfg.has_trajectory and scenario.loads_scenario(r.config_text).trajectory_values() == cfg.trajectory_values()
    # RMSE against the desired trajectory, eq. 43 over k = 0..N-1 on the true pose
    eta_d = cfg.trajectory().sample(r.t)[0]
    e = r.eta[:-1] - eta_d[:-1]
    np.testing.assert_allclose(r.rmse, np.sqrt((e**2).mean(axis=0)), rtol=1e-12)
    # the law saw the error to the reference that joins the trajectory, and the vehicle followed the move
    np.testing.assert_array_equal(r.e_seen[1:], (r.eta_hat - r.eta_ref)[1:])
    assert np.abs(r.eta[-1, :3] - [0.2, 0.05, 0.05]).max() < 0.02 and np.abs(e[r.t[:-1] > 6, :3]).max() < 0.02
    # the Python API on the same law (registered by the plugin), scenario and seed: the same run
    api = arvcas.Run("lab_task_pd", scenario=cfg).compile()
    p = api.simulate(seed=1)
    np.testing.assert_array_equal(p.rmse, r.rmse)
    np.testing.assert_array_equal(p.chat, r.chat)
    np.testing.assert_array_equal(p.eta, r.eta)
    chat, rmse = api.batch(api.default_gains()[None, :], seed=1)  # the metrics-only run agrees
    np.testing.assert_array_equal(rmse[0], r.rmse)
    # the printed table is the run's RMSE
    table = [line.split() for line in text.splitlines()[2:8]]
    np.testing.assert_allclose([float(row[2]) for row in table], r.rmse, rtol=1e-4)
