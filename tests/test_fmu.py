"""The FMI 2.0 FMU of the coupled vehicle + arm (arvcas.build.fmu, docs/fmu.md), checked with FMPy.

References are independent of the FMU's C wrapper: arvcas's own compiled ``uvms_rhs`` (the compile
cache) driven by integrators written here (the same fixed-step schemes on the same input samples),
and CasADi's CVODES on the SX graph. Inputs: the open-loop scenario of tests/test_integrator.py, i.e.
the scenario's arm motion (``arvcas.sim.profiles.joint_trajectory``, ``payload_profile``, evaluated
numerically) and a fixed thrust profile that cancels the net buoyancy until the payload, plus
sinusoids in every DOF.
"""

from __future__ import annotations

import contextlib
import ctypes
import shutil
import zipfile

import casadi as ca
import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy.fmi2 import FMU2Model, FMU2Slave  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from arvcas.build import fmu as fmu_mod  # noqa: E402
from arvcas.build.dynamics import compiled  # noqa: E402
from arvcas.util import files  # noqa: E402

from trust_helpers import bounded  # noqa: E402
from arvcas.sim import profiles, scenario  # noqa: E402

H = 0.01  # the FMU's default RK4 step (the scenario's former plant step, docs/model.md §4)
T_END = 30.0  # arm reach 5-20 s, payload ramp 22-22.5 s, return from 25 s
INPUTS = ([f"tau[{i}]" for i in range(1, 7)] + [f"{n}[{i}]" for n in ("q", "qd", "qdd") for i in range(1, 7)]
          + ["payload"])
STATES = [f"eta[{i}]" for i in range(1, 7)] + [f"nu[{i}]" for i in range(1, 7)]
PROFILE_FN: dict[str, ca.Function] = {}  # the input profile as a function of time (set by the fixture)


@pytest.fixture(scope="module")
def fmu_path(tmp_path_factory):
    return fmu_mod.export_fmu(tmp_path_factory.mktemp("fmu") / "uvms.fmu")


@pytest.fixture(scope="module")
def md(fmu_path):
    return fmpy.read_model_description(str(fmu_path))


@pytest.fixture(scope="module")
def profile(params):
    """Input samples on the grid t_k = k H, k = 0..T_END/H: (t, U[25, n]) in the order of INPUTS."""
    cfg = scenario.load_scenario()
    t = ca.SX.sym("t")
    q0 = ca.DM([params[f"arm.stow.q{i}"] for i in range(1, 7)])
    q, qd, qdd = profiles.joint_trajectory(cfg, q0, t)
    pl = profiles.payload_profile(cfg, t)
    net_buoyancy = params["vehicle.buoyancy_excess"] * params["env.g"]
    tau = ca.vertcat(5 * ca.sin(0.3 * t), 5 * ca.cos(0.2 * t), net_buoyancy * (1 - pl) + 3 * ca.sin(0.25 * t),
                     2 * ca.sin(0.4 * t), 3 * ca.sin(0.35 * t), 3 * ca.sin(0.15 * t))
    f = ca.Function("inputs", [t], [ca.vertcat(tau, q, qd, qdd, pl)])
    ts = H * np.arange(int(round(T_END / H)) + 1)
    U = np.array(f.map(ts.size)(ts.reshape(1, -1)))
    assert U.shape == (25, ts.size)
    assert np.ptp(U[6:12], axis=1).max() > 0.5 and U[24, -1] == 1.0  # the arm moves, the payload is on
    PROFILE_FN["inputs"] = f
    return ts, U


def _signals(ts, U):
    sig = np.zeros(ts.size, dtype=[("time", np.float64)] + [(n, np.float64) for n in INPUTS])
    sig["time"] = ts
    for i, n in enumerate(INPUTS):
        sig[n] = U[i]
    return sig


def _x0():
    cfg = scenario.load_scenario()
    return np.array([*cfg.initial_eta0, *cfg.initial_nu0])


def _states(res):
    return np.array([res[n] for n in STATES])


# ---------------------------------------------------------------------------------------------


def test_validation_and_description(fmu_path, md, params):
    assert validate_fmu(str(fmu_path)) == []
    assert md.fmiVersion == "2.0" and md.generationTool.startswith("arvcas ")
    assert md.modelExchange is not None and md.coSimulation is not None
    with zipfile.ZipFile(fmu_path) as zf:
        names = set(zf.namelist())
    assert f"binaries/linux64/{fmu_mod.MODEL_IDENTIFIER}.so" in names
    assert {"sources/fmi2Functions.h", f"sources/{fmu_mod.MODEL_IDENTIFIER}.c",
            "documentation/licenses/fmi2-headers.txt"} <= names
    by = {v.name: v for v in md.modelVariables}
    assert [v.name for v in md.modelVariables if v.causality == "input"] == INPUTS
    assert [by[n].causality for n in STATES] == ["output"] * 12
    assert [by[n].unit for n in STATES] == ["m"] * 3 + ["rad"] * 3 + ["m/s"] * 3 + ["rad/s"] * 3
    assert [d.variable.name for d in md.derivatives] == [f"der({n})" for n in STATES]
    assert [u.variable.name for u in md.outputs] == STATES
    # every parameter, with its SI value as start and the unit of its dimension
    for name in params.names():
        v = by[name]
        assert v.causality == "parameter" and float(v.start) == params[name]
    assert by["env.rho"].unit == "kg/m3" and by["arm.joint1.a"].unit == "m" and by["thrusters.delta_sL"].unit == "rad"
    assert by["tau[4]"].unit == "N.m" and by["qdd[1]"].unit == "rad/s2" and by["hydro.X_u"].unit is None
    # structure from the graph: eta_dot = J(eta) nu (docs/model.md §1) does not depend on the inputs
    deps = {d.variable.name: {k.name for k in d.dependencies} for d in md.derivatives}
    assert deps["der(eta[1])"] == {"eta[4]", "eta[5]", "eta[6]", "nu[1]", "nu[2]", "nu[3]"}
    assert deps["der(eta[4])"] == {"eta[4]", "eta[5]", "nu[4]", "nu[5]", "nu[6]"}
    assert set(INPUTS) <= deps["der(nu[1])"]


@contextlib.contextmanager
def _instance(path, md, name, cls=None, values=None):
    """An initialized FMPy instance of the FMU at ``path`` (Model Exchange in continuous-time mode,
    or ``cls=FMU2Slave``); ``values`` {name: value} set before initialization."""
    cls = cls or FMU2Model
    d = fmpy.extract(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    m = cls(guid=md.guid, unzipDirectory=d, modelIdentifier=fmu_mod.MODEL_IDENTIFIER, instanceName=name)
    try:
        m.instantiate()
        m.setupExperiment(startTime=0.0)
        if values:
            m.setReal([vr[n] for n in values], [float(v) for v in values.values()])
        m.enterInitializationMode()
        m.exitInitializationMode()
        if cls is FMU2Model:
            m.enterContinuousTimeMode()
        m.vr = vr
        yield m
        m.terminate()
        m.freeInstance()
    finally:
        shutil.rmtree(d, ignore_errors=True)


def _derivatives(m, names, x, u):
    """fmi2GetDerivatives at states x and inputs u (named ``names``)."""
    m.setReal([m.vr[n] for n in names], list(u))
    m.setContinuousStates(np.ctypeslib.as_ctypes(np.array(x, dtype=float)), 12)
    dx = np.zeros(12)
    m.getDerivatives(np.ctypeslib.as_ctypes(dx), 12)
    return dx


def _random_point(rng, u_scale):
    x = np.concatenate([rng.normal(size=3), rng.uniform(-0.5, 0.5, 3), rng.normal(size=6) * 0.3])
    u = np.concatenate([rng.normal(size=6) * u_scale, rng.uniform(-1.5, 1.5, 6), rng.normal(size=12) * 0.3,
                        rng.uniform(size=1)])
    return x, u


def test_derivatives_equal_compiled_rhs(fmu_path, md, params):
    """fmi2GetDerivatives at random states, inputs and parameters = arvcas.compiled("uvms_rhs")."""
    f = compiled("uvms_rhs")
    rng = np.random.default_rng(13)
    for trial in range(3):
        P = params.replace({"env.rho": float(rng.uniform(1000, 1030)), "vehicle.m": float(rng.uniform(4000, 4500)),
                            "arm.link3.mass": float(rng.uniform(5, 15))})
        p = P.vector()
        with _instance(fmu_path, md, f"i{trial}", values=P.as_dict()) as m:
            for _ in range(4):
                x, u = _random_point(rng, 100.0)
                m.setTime(float(rng.uniform(0, 100)))
                dx = _derivatives(m, INPUTS, x, u)
                ref = np.array(f(x, u[:6], u[6:12], u[12:18], u[18:24], u[24], p)).ravel()
                assert np.abs(ref).max() > 1e-2
                np.testing.assert_allclose(dx, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ref).max()))
                # the derivative variables and the outputs through fmi2GetReal
                assert m.getReal([m.vr[f"der({n})"] for n in STATES]) == list(dx)
                assert m.getReal([m.vr[n] for n in STATES]) == list(x)


def _rhs():
    """xdot = arvcas.compiled("uvms_rhs") at the 25 inputs u (order of INPUTS) and parameters pv."""
    f = compiled("uvms_rhs")

    def rhs(x, u, pv):
        return np.array(f(x, u[:6], u[6:12], u[12:18], u[18:24], u[24], pv)).ravel()

    return rhs


def test_model_exchange_euler_matches_same_scheme(fmu_path, profile, params):
    """FMPy's fixed-step Euler on the ME FMU = explicit Euler on compiled uvms_rhs with u(t_k)."""
    ts, U = profile
    res = fmpy.simulate_fmu(str(fmu_path), fmi_type="ModelExchange", solver="Euler", step_size=H,
                            output_interval=H, stop_time=T_END, input=_signals(ts, U), output=STATES)
    X = _states(res)
    rhs, p = _rhs(), params.vector()
    ref = np.empty((12, ts.size))
    ref[:, 0] = _x0()
    for k in range(ts.size - 1):
        ref[:, k + 1] = ref[:, k] + H * rhs(ref[:, k], U[:, k], p)
    assert X.shape == ref.shape
    assert np.abs(ref[:, -1] - ref[:, 0]).max() > 1e-2  # the vehicle does move
    err = np.abs(X - ref).max()
    print("ME Euler: max |FMU - reference| =", err)
    assert err < 1e-8


def _rk4_reference(ts, U, params, slopes):
    """Classic RK4 at H (arvcas's plant integration, docs/model.md §4) on compiled uvms_rhs; the inputs
    at the stage times t_k + s are U[:, k] + slopes[:, k] * s."""
    rhs, p = _rhs(), params.vector()
    ref = np.empty((12, ts.size))
    ref[:, 0] = _x0()
    for k in range(ts.size - 1):
        u0, du, x = U[:, k], slopes[:, k], ref[:, k]
        k1 = rhs(x, u0, p)
        k2 = rhs(x + 0.5 * H * k1, u0 + du * (0.5 * H), p)
        k3 = rhs(x + 0.5 * H * k2, u0 + du * (0.5 * H), p)
        k4 = rhs(x + H * k3, u0 + du * H, p)
        ref[:, k + 1] = x + H / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ref


def test_co_simulation_rk4_matches_arvcas_integration(fmu_path, profile, params):
    """fmpy.simulate_fmu on the CS FMU (RK4 at h_rk4 = 0.01 inside) = RK4 at h_plant on compiled
    uvms_rhs, the inputs held over each step as FMPy sets them."""
    ts, U = profile
    res = fmpy.simulate_fmu(str(fmu_path), fmi_type="CoSimulation", output_interval=H, stop_time=T_END,
                            input=_signals(ts, U), output=STATES)
    X = _states(res)
    ref = _rk4_reference(ts, U, params, np.zeros_like(U))
    assert X.shape == ref.shape
    assert np.abs(ref[:, -1] - ref[:, 0]).max() > 1e-2
    err = np.abs(X - ref).max()
    print("CS RK4, held inputs: max |FMU - reference| =", err)
    assert err < 1e-8


def _cs_master(fmu_path, md, U, derivs, ts):
    """A Co-Simulation master loop on FMU2Slave: at each t_k set the inputs U[:, k] and their time
    derivatives derivs[order] (order 1, 2: arrays like U), then fmi2DoStep(t_k, H). (FMPy's
    simulate_fmu sizes its input-derivative buffer for 9 inputs, so the loop is written here.)"""
    with _instance(fmu_path, md, "cs", cls=FMU2Slave) as sl:
        vin, vout = [sl.vr[n_] for n_ in INPUTS], [sl.vr[n_] for n_ in STATES]
        X = np.empty((12, ts.size))
        X[:, 0] = sl.getReal(vout)
        for k in range(ts.size - 1):
            sl.setReal(vin, list(U[:, k]))
            for order, D in derivs.items():
                sl.setRealInputDerivatives(vin, [order] * 25, list(D[:, k]))
            sl.doStep(currentCommunicationPoint=ts[k], communicationStepSize=H)
            X[:, k + 1] = sl.getReal(vout)
        u_end = np.array(sl.getReal(vin))
    return X, u_end


def test_co_simulation_interpolated_inputs(fmu_path, md, profile, params):
    """fmi2SetRealInputDerivatives (order 1): the inputs are linear over each communication step, so
    the RK4 stages see the piecewise-linear interpolation of the samples at their own times."""
    ts, U = profile
    n = 600  # the arm is moving from 5 s on: 0-6 s covers the start of the reach
    ts, U = ts[: n + 1], U[:, : n + 1]
    slopes = np.zeros_like(U)
    slopes[:, :-1] = np.diff(U, axis=1) / H
    X, u_end = _cs_master(fmu_path, md, U, {1: slopes}, ts)
    np.testing.assert_allclose(u_end, U[:, n], rtol=0, atol=1e-12)  # after the step: the end of the line
    ref = _rk4_reference(ts, U, params, slopes)
    held = _rk4_reference(ts, U, params, np.zeros_like(U))
    err = np.abs(X - ref).max()
    print("CS RK4, interpolated inputs: max |FMU - reference| =", err, "; vs held inputs:", np.abs(X - held).max())
    assert err < 1e-8
    assert np.abs(X - held).max() > 1e3 * max(err, 1e-15)  # the derivatives were used


def test_co_simulation_matches_arvcas_plant_integration(fmu_path, md, profile, params):
    """The scenario's thrust profile and arm motion through the CS FMU, the master passing the exact
    first and second time derivatives of the inputs, against arvcas's plant integration (docs/model.md
    §4): classic RK4 at h_plant with every input evaluated at the stage times t_k, t_k + h/2, t_k + h.
    The FMU sees the inputs as their second-order Taylor expansion about t_k, off at the stage times by
    about h^3/6 times the third derivative (a linear interpolation of the samples would give 2.4e-8)."""
    ts, U = profile
    f = PROFILE_FN["inputs"]
    t = ca.SX.sym("t")
    d1 = ca.jacobian(f(t), t)
    d2 = ca.jacobian(d1, t)
    fd = ca.Function("dinputs", [t], [d1, d2]).map(ts.size - 1)
    D1, D2 = (np.array(a) for a in fd((ts[:-1] + 1e-12).reshape(1, -1)))  # right-hand limits at the kinks
    X, _ = _cs_master(fmu_path, md, U, {1: D1, 2: D2}, ts)
    rhs, p = _rhs(), params.vector()
    Um = np.array(f.map(ts.size - 1)((ts[:-1] + 0.5 * H).reshape(1, -1)))
    ref = np.empty((12, ts.size))
    ref[:, 0] = _x0()
    for k in range(ts.size - 1):
        x = ref[:, k]
        k1 = rhs(x, U[:, k], p)
        k2 = rhs(x + 0.5 * H * k1, Um[:, k], p)
        k3 = rhs(x + 0.5 * H * k2, Um[:, k], p)
        k4 = rhs(x + H * k3, U[:, k + 1], p)
        ref[:, k + 1] = x + H / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    err = np.abs(X - ref).max()
    print("CS RK4 with exact input derivatives vs arvcas's RK4 at the stage times:", err)
    assert np.abs(ref[:, -1] - ref[:, 0]).max() > 1e-2
    assert err < 1e-8


def test_model_exchange_cvode_matches_cvodes(fmu_path, md, params, plant):
    """FMPy's CVode on the ME FMU, constant inputs (arm at the grasp pose, payload on, a constant
    wrench), against CasADi's CVODES on the SX graph of uvms_rhs, both at tight tolerances."""
    cfg = scenario.load_scenario()
    u = np.concatenate([[3.0, -2.0, 1.0, 2.0, -4.0, 1.5], cfg.arm_qg, np.zeros(12), [1.0]])
    T = 10.0
    start = dict(zip(INPUTS, map(float, u)))
    res = fmpy.simulate_fmu(str(fmu_path), fmi_type="ModelExchange", solver="CVode", relative_tolerance=1e-12,
                            output_interval=0.1, stop_time=T, start_values=start, output=STATES)
    X = _states(res)
    x = ca.SX.sym("x", 12)
    xdot = plant["uvms_rhs"](x, u[:6], u[6:12], u[12:18], u[18:24], u[24], params.vector())
    grid = list(0.1 * np.arange(1, int(round(T / 0.1)) + 1))
    integ = ca.integrator("ref", "cvodes", {"x": x, "ode": xdot}, 0.0, grid,
                          dict(abstol=1e-14, reltol=1e-14, max_num_steps=1_000_000,
                               linear_multistep_method="adams", nonlinear_solver_iteration="functional"))
    ref = np.hstack([_x0()[:, None], np.array(integ(x0=_x0())["xf"])])
    assert X.shape == ref.shape
    assert np.abs(ref[:, -1] - ref[:, 0]).max() > 1e-2
    err = np.abs(X - ref).max()
    print("ME CVode vs CVODES: max difference =", err)
    assert err < 1e-8


def test_thruster_inputs_params_and_options(tmp_path, params):
    """inputs="thrusters": the derivatives are uvms_rhs at tau = thrust(u) = B_T sat(u); the FMU's
    parameter start values are the Params given (here with a dry vehicle, rho = 0, and a heavier link),
    and ModelOptions reach the generated graph (n_quad = 3, against compiled("uvms_rhs", opts))."""
    from arvcas.model.uvms import ModelOptions

    opts = ModelOptions(n_quad=3)
    P = params.replace({"env.rho": 0.0, "arm.link2.mass": 30.0})
    path = fmu_mod.export_fmu(tmp_path / "thr.fmu", system=P, opts=opts, inputs="thrusters")
    assert validate_fmu(str(path)) == []
    md = fmpy.read_model_description(str(path))
    names = [f"u[{i}]" for i in range(1, 7)] + INPUTS[6:]
    assert [v.name for v in md.modelVariables if v.causality == "input"] == names
    assert {v.name: float(v.start) for v in md.modelVariables if v.causality == "parameter"}["env.rho"] == 0.0
    f, thrust, p = compiled("uvms_rhs", opts), compiled("thrust"), P.vector()
    rng = np.random.default_rng(4)
    with _instance(path, md, "t") as m:
        for _ in range(3):
            x, u = _random_point(rng, 300.0)  # beyond the thrusters' limits [-146.9, 231.6] N
            dx = _derivatives(m, names, x, u)
            ref = np.array(f(x, thrust(u[:6], p), u[6:12], u[12:18], u[18:24], u[24], p)).ravel()
            np.testing.assert_allclose(dx, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ref).max()))


def test_fmu_state_get_set_serialize(fmu_path, md, profile):
    """fmi2GetFMUstate / fmi2SetFMUstate and (de)serialization: rewinding a Co-Simulation instance and
    stepping again gives the same states, bit for bit; a Model Exchange instance gets its states back."""
    ts, U = profile
    with _instance(fmu_path, md, "cs", cls=FMU2Slave) as sl:
        vin, vout = [sl.vr[n] for n in INPUTS], [sl.vr[n] for n in STATES]

        def run(k0, k1):
            out = []
            for k in range(k0, k1):
                sl.setReal(vin, list(U[:, k]))
                sl.doStep(currentCommunicationPoint=ts[k], communicationStepSize=H)
                out.append(sl.getReal(vout))
            return np.array(out)

        run(0, 600)
        st = sl.getFMUstate()
        blob = sl.serializeFMUstate(st)
        first = run(600, 800)
        sl.setFMUstate(st)
        again = run(600, 800)
        st2 = sl.deSerializeFMUstate(blob)
        sl.setFMUstate(st2)
        third = run(600, 800)
        sl.freeFMUstate(st)
        sl.freeFMUstate(st2)
        assert np.abs(first[-1] - first[0]).max() > 1e-4  # the state moved in between
        assert np.array_equal(first, again) and np.array_equal(first, third)
        with pytest.raises(Exception):
            sl.deSerializeFMUstate(blob[:-1])
    with _instance(fmu_path, md, "me") as m:
        x0 = np.array(m.getReal([m.vr[n] for n in STATES]))
        st = m.getFMUstate()
        m.setContinuousStates(np.ctypeslib.as_ctypes(np.ones(12)), 12)
        m.setFMUstate(st)
        m.freeFMUstate(st)
        assert np.array_equal(m.getReal([m.vr[n] for n in STATES]), x0)


def test_wrong_guid_and_parameters_after_init_refused(fmu_path, md):
    from fmpy.fmi1 import FMICallException

    d = fmpy.extract(str(fmu_path))
    try:
        bad = FMU2Model(guid="{00000000-0000-0000-0000-000000000000}", unzipDirectory=d,
                        modelIdentifier=fmu_mod.MODEL_IDENTIFIER, instanceName="bad")
        with pytest.raises(Exception, match="instantiate"):
            bad.instantiate()
    finally:
        shutil.rmtree(d, ignore_errors=True)
    with _instance(fmu_path, md, "ok") as m:
        with pytest.raises(FMICallException):
            m.setReal([m.vr["env.rho"]], [0.0])


def test_do_step_is_bounded_and_checks_the_communication_point(fmu_path, md, capsys):
    """A huge communication step or a tiny h_rk4 (1e10+ RK4 steps) is refused before any work, one logged
    message; so is a currentCommunicationPoint that is not the instance's time."""
    from fmpy.fmi1 import FMICallException

    cases = [(None, 0.0, 1e9, "more than 1000000 RK4 steps"), ({"h_rk4": 1e-12}, 0.0, 0.01, "more than 1000000"),
             (None, 5.0, 0.01, "currentCommunicationPoint is not the instance's current time")]
    for values, tc, H, message in cases:
        with _instance(fmu_path, md, "cs", cls=FMU2Slave, values=values) as sl:
            capsys.readouterr()
            e = bounded(lambda: sl.doStep(currentCommunicationPoint=tc, communicationStepSize=H))
            assert isinstance(e, FMICallException), repr(e)
            assert message in capsys.readouterr().out
            if values is None:  # the instance goes on with a step it can take
                sl.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.01)
                sl.doStep(currentCommunicationPoint=0.01, communicationStepSize=0.01)


def test_ranges_declared_and_checked_with_a_logged_message(fmu_path, md, capsys):
    """min/max in the model description; parameters checked at initialization by the loader's rules, NaN
    states and out-of-range inputs refused by fmi2SetReal / fmi2SetContinuousStates (fmi2Error, logged)."""
    from fmpy.fmi1 import FMICallException

    var = {v.name: v for v in md.modelVariables}
    assert (var["payload"].min, var["payload"].max) == ("0.0", "1.0") and var["vehicle.m"].min == "0.0"
    assert var["h_rk4"].min == "0.0" and var["vehicle.xG"].min is None
    cases = [({"vehicle.m": -1.0}, "fmi2ExitInitializationMode: vehicle.m = -1: must be > 0"),
             ({"thrusters.u_min": 500.0}, "thrusters.u_min = 500: must be below its upper limit"),
             ({"arm.stow.q1": 3.5}, "arm.stow.q1 = 3.5: outside its joint's limits"),
             ({"env.rho": float("nan")}, "env.rho = nan: not a finite number")]
    for values, message in cases:
        with pytest.raises(FMICallException):
            with _instance(fmu_path, md, "bad", values=values):
                pass
        assert message in capsys.readouterr().out
    with _instance(fmu_path, md, "me") as m:
        capsys.readouterr()
        for vr, v, message in ((m.vr["payload"], 1.5, "payload = 1.5: outside [0, 1]"),
                               (m.vr["tau[3]"], float("inf"), "tau[3] = inf: not a finite number")):
            with pytest.raises(FMICallException):
                m.setReal([vr], [v])
            assert message in capsys.readouterr().out
        x = np.full(12, 0.1)
        x[4] = np.nan
        with pytest.raises(FMICallException):
            m.setContinuousStates(x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), 12)
        assert "fmi2SetContinuousStates: eta[5] = nan: not a finite number" in capsys.readouterr().out
        m.setReal([m.vr["payload"]], [1.0])  # the instance goes on


# ---------------------------------------------------------------------------------------------
# arguments and files


@pytest.mark.parametrize("bad, match", [
    ("model.zip", r"^path: the file name must end in \.fmu, got 'model.zip'$"),
    ("missing/dir/model.fmu", r"^path: directory .*missing/dir does not exist$"),
])
def test_bad_path_one_line(tmp_path, bad, match):
    with pytest.raises(fmu_mod.FMUError, match=match) as e:
        fmu_mod.export_fmu(tmp_path / bad)
    assert "\n" not in str(e.value)


def test_bad_inputs_one_line(tmp_path):
    with pytest.raises(fmu_mod.FMUError, match=r"^inputs: expected one of wrench, thrusters, got 'torque'$"):
        fmu_mod.export_fmu(tmp_path / "a.fmu", inputs="torque")
    assert not (tmp_path / "a.fmu").exists()


def test_foreign_file_refused_then_forced(tmp_path, fmu_path):
    foreign = tmp_path / "other.fmu"
    foreign.write_bytes(b"not written by arvcas")
    with pytest.raises(fmu_mod.FMUError, match=r"^path: .*other\.fmu exists and is not an FMU written by arvcas; "
                                              r"pass force=True \(--force\) to replace it$"):
        fmu_mod.export_fmu(foreign)
    assert foreign.read_bytes() == b"not written by arvcas"
    # a zip with another tool's modelDescription is foreign too
    other = tmp_path / "tool.fmu"
    with zipfile.ZipFile(other, "w") as zf:
        zf.writestr("modelDescription.xml", '<fmiModelDescription fmiVersion="2.0" generationTool="OpenModelica"/>')
    before = other.read_bytes()
    with pytest.raises(fmu_mod.FMUError, match="not an FMU written by arvcas"):
        fmu_mod.export_fmu(other)
    assert other.read_bytes() == before
    # an FMU arvcas wrote (recorded in the directory's manifest) may be replaced; nothing is compiled or
    # unpacked to decide that; a copy made by someone else is not arvcas's, whatever it says inside
    mine = tmp_path / "mine.fmu"
    shutil.copyfile(fmu_path, mine)
    with pytest.raises(fmu_mod.FMUError, match="not an FMU written by arvcas"):
        fmu_mod._check_path(mine, force=False)
    mine.unlink()
    files.atomic_write(mine, lambda t: shutil.copyfile(fmu_path, t), kind=fmu_mod.KIND)
    assert fmu_mod._check_path(mine, force=False) == mine
    # a symbolic link is not replaced, even one to an FMU arvcas wrote
    link = tmp_path / "link.fmu"
    link.symlink_to(mine)
    with pytest.raises(fmu_mod.FMUError, match=r"^path: .*link\.fmu is a symbolic link; pass force=True"):
        fmu_mod.export_fmu(link)
    link.unlink()
    # force replaces the foreign file with a valid FMU, atomically (no temporary left behind)
    out = fmu_mod.export_fmu(foreign, force=True)
    assert out == foreign and validate_fmu(str(out)) == []
    # no temporary left; the one writer records what arvcas wrote in the directory's manifest
    assert sorted(p.name for p in tmp_path.iterdir()) == [".arvcas-manifest.json", "mine.fmu", "other.fmu", "tool.fmu"]


# ---------------------------------------------------------------------------------------------
# another system: the BlueROV2 Heavy + Reach Alpha 5 (8 thrusters, 4 joints, 239 parameters)

BLUEROV2 = "bluerov2_heavy_alpha5"
T_END_B = 3.0  # a few seconds: the vehicle moves, the arm swings


@pytest.fixture(scope="module")
def bluerov2():
    from arvcas.system import load_system

    return load_system(BLUEROV2)


@pytest.fixture(scope="module")
def bluerov2_fmu(tmp_path_factory, bluerov2):
    """``arvcas export-fmu --system bluerov2_heavy_alpha5 FILE.fmu``, the command line."""
    from arvcas import cli

    path = tmp_path_factory.mktemp("fmu_b") / "bluerov2.fmu"
    assert cli.main(["export-fmu", "--system", BLUEROV2, str(path)]) == 0
    return path


def _input_names(system, first="tau"):
    n_in = 6 if first == "tau" else system.n_thrusters
    nj = system.n_joints
    return ([f"{first}[{i}]" for i in range(1, n_in + 1)] + [f"{n}[{i}]" for n in ("q", "qd", "qdd")
                                                               for i in range(1, nj + 1)] + ["payload"])


def _split(u, n_in, nj):
    """The FMU's inputs in order -> the uvms_rhs arguments (first, q, qd, qdd, payload)."""
    return u[:n_in], u[n_in:n_in + nj], u[n_in + nj:n_in + 2 * nj], u[n_in + 2 * nj:n_in + 3 * nj], u[-1]


@pytest.fixture(scope="module")
def bluerov2_profile(bluerov2):
    """(t, U) on t_k = k H over T_END_B: a wrench of sinusoids, each joint swinging about the stowed
    pose (q, qd, qdd consistent), the payload ramped on from 1 s to 2 s."""
    P, nj = bluerov2.params, bluerov2.n_joints
    t = ca.SX.sym("t")
    q0 = ca.DM([P[f"arm.stow.q{i}"] for i in range(1, nj + 1)])
    w = ca.DM([0.8 + 0.3 * i for i in range(nj)])
    q = q0 + 0.3 * ca.sin(w * t)
    qd, qdd = 0.3 * w * ca.cos(w * t), -0.3 * w * w * ca.sin(w * t)
    pl = ca.fmin(ca.fmax(t - 1.0, 0.0), 1.0)
    tau = ca.vertcat(8 * ca.sin(0.9 * t), 6 * ca.cos(0.7 * t), 5 * ca.sin(1.1 * t), 0.5 * ca.sin(1.3 * t),
                     0.6 * ca.sin(0.8 * t), 0.7 * ca.cos(1.2 * t))
    f = ca.Function("inputs_b", [t], [ca.vertcat(tau, q, qd, qdd, pl)])
    ts = H * np.arange(int(round(T_END_B / H)) + 1)
    U = np.array(f.map(ts.size)(ts.reshape(1, -1)))
    assert U.shape == (6 + 3 * nj + 1, ts.size) and U[-1, -1] == 1.0
    return ts, U


def _x0_of(system):
    cfg = scenario.load_scenario(system.params.default("scenario"))
    return np.array([*cfg.initial_eta0, *cfg.initial_nu0])


def test_bluerov2_validation_and_description(bluerov2_fmu, bluerov2):
    """The FMU is sized by the system: 6 + 3 * 4 + 1 inputs, its parameters with their SI units (an SI
    hydrodynamic coefficient with its term's unit; the thrust table's points as arrays), h_rk4 and the
    parameters after the inputs."""
    assert validate_fmu(str(bluerov2_fmu)) == []
    md = fmpy.read_model_description(str(bluerov2_fmu))
    P, names = bluerov2.params, _input_names(bluerov2)
    assert md.modelExchange is not None and md.coSimulation is not None and BLUEROV2 in md.description
    by = {v.name: v for v in md.modelVariables}
    assert [v.name for v in md.modelVariables if v.causality == "input"] == names
    assert len(names) == 6 + 3 * bluerov2.n_joints + 1 == 19
    assert [u.variable.name for u in md.outputs] == STATES
    assert [d.variable.name for d in md.derivatives] == [f"der({n})" for n in STATES]
    params = [v for v in md.modelVariables if v.causality == "parameter" and v.name != "h_rk4"]
    assert [v.name for v in params] == [fmu_mod.fmi_name(n) for n in P.names()] and len(params) == len(P) == 649
    assert by["thrusters.map.t200_16v.thrust[200]"].unit == "N" and by["thrusters.T1.time_constant"].unit == "s"
    assert [float(v.start) for v in params] == list(P.vector())
    lay = fmu_mod.layout(P)
    assert lay["vr_h"] == by["h_rk4"].valueReference == 24 + 19 and params[0].valueReference == lay["vr_p"]
    assert by["env.rho"].unit == "kg/m3" and by["thrusters.T1.u_max"].unit == "N"
    assert by["arm.joint1.roll"].unit == "rad" and by["arm.joint1.roll"].displayUnit == "deg"
    assert by["hydro.X_u_absu"].unit == "kg/m" and by["hydro.X_udot"].unit == "kg"
    assert by["hydro.K_p_absp"].unit == "kg.m2/rad2"
    units = {u.name: u.baseUnit for u in md.unitDefinitions}
    assert (units["kg/m"].kg, units["kg/m"].m) == (1, -1)
    assert [float(by[f"q[{j}]"].start) for j in range(1, 5)] == [P[f"arm.stow.q{j}"] for j in range(1, 5)]
    np.testing.assert_array_equal([float(by[n].start) for n in STATES], _x0_of(bluerov2))
    deps = {d.variable.name: {k.name for k in d.dependencies} for d in md.derivatives}
    assert deps["der(eta[1])"] == {"eta[4]", "eta[5]", "eta[6]", "nu[1]", "nu[2]", "nu[3]"}
    assert set(names) <= deps["der(nu[1])"]


def test_bluerov2_derivatives_equal_compiled_rhs(bluerov2_fmu, bluerov2):
    md = fmpy.read_model_description(str(bluerov2_fmu))
    f, p, nj = compiled("uvms_rhs", system=bluerov2), bluerov2.params.vector(), bluerov2.n_joints
    names = _input_names(bluerov2)
    rng = np.random.default_rng(7)
    with _instance(bluerov2_fmu, md, "b") as m:
        for _ in range(4):
            x = np.concatenate([rng.normal(size=3), rng.uniform(-0.5, 0.5, 3), rng.normal(size=6) * 0.3])
            u = np.concatenate([rng.normal(size=6) * 20, rng.uniform(-1.5, 1.5, nj), rng.normal(size=2 * nj) * 0.3,
                                rng.uniform(size=1)])
            dx = _derivatives(m, names, x, u)
            ref = np.array(f(x, *_split(u, 6, nj), p)).ravel()
            assert np.abs(ref).max() > 1e-2
            np.testing.assert_allclose(dx, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ref).max()))


def test_bluerov2_simulate_fmu_matches_arvcas_integration(bluerov2_fmu, bluerov2, bluerov2_profile):
    """fmpy.simulate_fmu, Model Exchange with Euler and Co-Simulation (RK4 at h_rk4 = H inside), over
    T_END_B = 3 s, against the same schemes on arvcas's compiled uvms_rhs of the system, inputs held."""
    ts, U = bluerov2_profile
    names, nj = _input_names(bluerov2), bluerov2.n_joints
    sig = np.zeros(ts.size, dtype=[("time", np.float64)] + [(n, np.float64) for n in names])
    sig["time"] = ts
    for i, n in enumerate(names):
        sig[n] = U[i]
    f, p = compiled("uvms_rhs", system=bluerov2), bluerov2.params.vector()

    def rhs(x, u):
        return np.array(f(x, *_split(u, 6, nj), p)).ravel()

    euler, rk4 = np.empty((12, ts.size)), np.empty((12, ts.size))
    euler[:, 0] = rk4[:, 0] = _x0_of(bluerov2)
    for k in range(ts.size - 1):
        u, x = U[:, k], rk4[:, k]
        euler[:, k + 1] = euler[:, k] + H * rhs(euler[:, k], u)
        k1 = rhs(x, u)
        k2 = rhs(x + 0.5 * H * k1, u)
        k3 = rhs(x + 0.5 * H * k2, u)
        k4 = rhs(x + H * k3, u)
        rk4[:, k + 1] = x + H / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    assert np.abs(euler - rk4).max() > 1e-6  # the two schemes are told apart
    for fmi_type, kw, ref in (("ModelExchange", dict(solver="Euler", step_size=H), euler),
                              ("CoSimulation", {}, rk4)):
        res = fmpy.simulate_fmu(str(bluerov2_fmu), fmi_type=fmi_type, output_interval=H, stop_time=T_END_B,
                                input=sig, output=STATES, **kw)
        X = _states(res)
        assert X.shape == ref.shape
        assert np.abs(ref[:, -1] - ref[:, 0]).max() > 1e-2  # the vehicle does move
        err = np.abs(X - ref).max()
        print(f"BlueROV2 {fmi_type}: max |FMU - reference| =", err)
        assert err < 1e-8, fmi_type


def test_bluerov2_thruster_inputs(tmp_path, bluerov2):
    """inputs="thrusters" on the BlueROV2: its eight thrusters by name, derivatives = uvms_rhs at
    tau = thrust(u) = B_T sat(u) of the system."""
    path = fmu_mod.export_fmu(tmp_path / "thr_b.fmu", system=BLUEROV2, inputs="thrusters")
    assert validate_fmu(str(path)) == []
    md = fmpy.read_model_description(str(path))
    names, nt, nj = _input_names(bluerov2, "u"), bluerov2.n_thrusters, bluerov2.n_joints
    ins = [v for v in md.modelVariables if v.causality == "input"]
    assert [v.name for v in ins] == names and len(names) == nt + 3 * nj + 1 == 21
    assert "thruster T8" in ins[7].description
    f, thrust, p = compiled("uvms_rhs", system=bluerov2), compiled("thrust", system=bluerov2), bluerov2.params.vector()
    rng = np.random.default_rng(5)
    with _instance(path, md, "tb") as m:
        for _ in range(3):
            x = np.concatenate([rng.normal(size=3), rng.uniform(-0.5, 0.5, 3), rng.normal(size=6) * 0.3])
            u = np.concatenate([rng.normal(size=nt) * 40, rng.uniform(-1.5, 1.5, nj), rng.normal(size=2 * nj) * 0.3,
                                rng.uniform(size=1)])  # beyond the T200's +-30.4 N: saturated
            dx = _derivatives(m, names, x, u)
            first, *rest = _split(u, nt, nj)
            ref = np.array(f(x, thrust(first, p), *rest, p)).ravel()
            np.testing.assert_allclose(dx, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ref).max()))
