"""Logs of thruster commands (with the thruster dynamics): a log that maps the PWM
each thruster was sent drives the open-loop plant through the system's rotor lag and command map.

The system is the shipped BlueROV2 Heavy without its arm (a vehicle-only system keeps the compiled code
small) with its T200s (16 V table, one time constant). The references are independent of the log plant:
SciPy's DOP853 of the rotor ODE ``ds/dt = (y - s) / tau`` with SciPy's own PchipInterpolator through the
table's points (the dead band taken out) and the public ``vehicle_rhs``; central finite differences of
the simulation for the sensitivities to the thrusters' parameters.
"""

from __future__ import annotations

import numpy as np
import pytest
import tomlkit

import arvcas
from arvcas.cli import main
from arvcas.ident import logs, plant, validate

RATE = 50.0


@pytest.fixture(scope="module")
def rov(tmp_path_factory):
    src = arvcas.load_system("bluerov2_heavy_alpha5").path
    doc = tomlkit.parse(open(src, encoding="utf-8").read())
    for k in ("arm", "payload", "defaults"):
        doc.pop(k, None)
    doc["system"]["name"] = "bluerov2_vehicle"
    d = tmp_path_factory.mktemp("rov")
    path = d / "bluerov2_vehicle.toml"
    path.write_text(tomlkit.dumps(doc))
    return arvcas.load_system(path)


def _commands(seed: int, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """(t, C (N x 8)): PWM steps every 0.3 s, some inside the dead band (1472-1528 us), logged at RATE."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration * RATE)) + 1) / RATE
    k = (t / 0.3).astype(int)
    levels = rng.choice([1300.0, 1420.0, 1500.0, 1560.0, 1680.0, 1740.0], size=(k.max() + 1, 8))
    return t, levels[k]


def _write(d, name: str, t, C, unit: str = "us", extra: str = "") -> str:
    cols = [f"T{i + 1}" for i in range(8)]
    np.savetxt(d / f"{name}_cmd.csv", np.column_stack([t, C]), delimiter=",", header=",".join(["t"] + cols),
               comments="", fmt="%.10g")
    rows = "\n".join(f'{c} = {{ columns = ["{c}"], unit = "{unit}" }}' for c in cols)
    text = f"""[log]
name = "{name}"
rate = {RATE}

[[stream]]
file = "{name}_cmd.csv"
time = "t"
[stream.command]
{rows}
{extra}"""
    path = d / f"{name}.log.toml"
    path.write_text(text)
    return path


def test_commanded_log_against_scipy(rov, tmp_path):
    from scipy.integrate import solve_ivp
    from scipy.interpolate import PchipInterpolator

    t, C = _commands(1, 3.0)
    lg = logs.load_log(_write(tmp_path, "c1", t, C), n_joints=0, thruster_names=rov.structure.thrusters)
    assert set(lg.command) == {f"T{i + 1}" for i in range(8)} and lg.command_unit["T1"] == "us"
    assert np.array_equal(lg.command["T3"], C[:, 2])
    # the table from its CSV, the dead band's run of zero thrust taken out: s = c - 1472 below, c - 1528 above
    tab = np.loadtxt(arvcas.system.shipped()["bluerov2_heavy_alpha5"].parent / "t200_16v.csv", delimiter=",",
                     comments="#", skiprows=9)
    c, f = tab[:, 0], tab[:, 1] * 9.80665
    zero = np.flatnonzero(f == 0)
    lo, hi = c[zero[0]], c[zero[-1]]
    assert (lo, hi) == (1472.0, 1528.0)
    s_pts = np.r_[c[: zero[0] + 1] - lo, c[zero[-1] + 1:] - hi]
    F = PchipInterpolator(s_pts, np.r_[f[: zero[0] + 1], f[zero[-1] + 1:]])
    tau = rov.params["thrusters.T1.time_constant"]
    import casadi as ca

    from arvcas.model import thrusters as thr
    from arvcas.system.params import view

    P = view(ca.DM(rov.params.vector()), rov.layout)

    B = np.array(thr.B_T(P), dtype=float)
    rhs_v = arvcas.dynamics("vehicle_rhs", rov)
    y_of = lambda cc: np.where(cc > hi, cc - hi, np.where(cc < lo, cc - lo, 0.0))  # noqa: E731

    x = np.r_[np.zeros(12), y_of(C[0])]  # the rotors at the first command's steady state
    ref = [x[:12]]
    for k in range(len(t) - 1):
        y = y_of(C[k])

        def rhs(_, z, y=y):
            return np.r_[rhs_v(z[:12], B @ F(z[12:])).reshape(-1), (y - z[12:]) / tau]

        x = solve_ivp(rhs, (t[k], t[k + 1]), x, method="DOP853", rtol=1e-11, atol=1e-12).y[:, -1]
        ref.append(x[:12])
    ref = np.array(ref)
    assert np.max(np.abs(ref[:, 6:9])) > 0.05  # the thrusters did move the vehicle
    errs = []
    for m in (2, 16):
        X = plant.simulate(plant.LogPlant(rov, m=m), lg, np.zeros(12), rov.params.vector())
        errs.append(np.max(np.abs(X - ref)))
    # RK4 with the exact thrust at its stage times converges to SciPy's solution, at a reduced order: after a
    # command's jump the rotor sweeps up to a hundred of the table's points within a step, and the cubic
    # pieces join with jumps of their second derivative (docs/model.md §9). Measured on 1 s of these
    # commands: 4.0e-4, 1.7e-4, 8.1e-5, 1.4e-5 for h = 5, 2.5, 1.25, 0.625 ms; with the commands held constant
    # the order is four (1.8e-5, 1.1e-6, 6.9e-8, 4.3e-9 for h = 20 ... 2.5 ms). Here (3 s): 7.9e-4 at
    # 10 ms, 8.2e-5 at 1.25 ms
    assert errs[1] < 2e-4 and errs[0] / errs[1] > 5, errs


def test_commanded_sensitivities_to_thruster_parameters(rov, tmp_path):
    """d x / d theta through the rotor path (time constant, one table point) and a hydrodynamic derivative,
    against central differences of the simulation."""
    t, C = _commands(2, 1.5)
    lg = logs.load_log(_write(tmp_path, "c2", t, C), n_joints=0, thruster_names=rov.structure.thrusters)
    free = ("thrusters.T1.time_constant", "thrusters.map.t200_16v.thrust.150", "hydro.N_r_absr")
    lay = rov.layout
    pl = plant.LogPlant(rov, m=2, free=free)
    assert pl.thrust_free == free[:2]
    p = rov.params.vector()
    idx = [lay.index[n] for n in free]
    th = p[idx].copy()
    d = dict(plant.sample_inputs(lg, rov, 2, p=p))
    part = plant.rotor_thrust_sens(lg, rov, 2, p, free[:2])
    n = part.shape[1] // 2
    full = np.zeros((part.shape[0], 3, n))
    full[:, :2, :] = part.reshape(part.shape[0], 2, n, order="F")
    d["dU"] = full.reshape(part.shape[0], 3 * n, order="F")
    x0 = np.zeros(12)
    X, dX = plant.simulate_sens(pl, lg, x0, p, th, data=d)
    for j, name in enumerate(free):
        eps = 1e-6 * abs(th[j])

        def sim(v):
            pv = p.copy()
            pv[idx[j]] = v
            return plant.simulate(pl, lg, x0, pv, data=plant.sample_inputs(lg, rov, 2, p=pv))

        fd = (sim(th[j] + eps) - sim(th[j] - eps)) / (2 * eps)
        assert np.max(np.abs(fd)) > 1e-6, name  # the parameter moves the vehicle
        assert np.max(np.abs(fd - dX[:, :, 12 + j])) <= 1e-5 * np.max(np.abs(fd)), name


@pytest.mark.parametrize("case, match", [
    ("range", r"command\.T2: 1950 us at t = .* is outside the range of its map t200_16v \(\[1100, 1900\] us\)"),
    ("unit", r"command\.T1\.unit: '1', but its map t200_16v takes commands in 'us'"),
    ("nodyn", r"has no thruster dynamics \(no command map\): map the thrusters' thrust instead"),
    ("both", r"commands and thrust in one log"),
])
def test_commanded_log_refusals(rov, tmp_path, capsys, case, match):
    t, C = _commands(3, 1.0)
    system, extra, unit = "bluerov2_vehicle.toml", "", "us"
    if case == "range":
        C[10, 1] = 1950.0
    if case == "unit":
        unit = "1"
    if case == "nodyn":
        system = "hinsdale_bluerov2_alpha5"
    if case == "both":
        np.savetxt(tmp_path / "thr.csv", np.column_stack([t, np.zeros_like(t)]), delimiter=",", header="t,f",
                   comments="")
        extra = '\n[[stream]]\nfile = "thr.csv"\ntime = "t"\n[stream.thrust]\nT5 = { columns = ["f"], unit = "N" }\n'
    path = _write(tmp_path, "bad", t, C, unit=unit, extra=extra)
    sysarg = str(rov.path) if system.endswith(".toml") else system
    if case == "nodyn":  # a vehicle-only system without maps: the Hinsdale vehicle has the same thruster names
        src = arvcas.load_system("hinsdale_bluerov2_alpha5").path
        doc = tomlkit.parse(open(src, encoding="utf-8").read())
        for k in ("arm", "payload", "defaults"):
            doc.pop(k, None)
        doc["system"]["name"] = "hinsdale_vehicle"
        (tmp_path / "hv.toml").write_text(tomlkit.dumps(doc))
        sysarg = str(tmp_path / "hv.toml")
    out = tmp_path / "out"
    rc = main(["validate", "--system", sysarg, str(path), "--out", str(out)])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and __import__("re").search(match, err[0]), err
    assert not out.exists()
