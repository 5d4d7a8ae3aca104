"""Identification that cannot leave physics, and an identified file that loads wherever it is written.

* the rigid-body map (arvcas.ident.physical.Mapping) against independent checks: the loader's own
  check_physical and NumPy's eigenvalues of the inertia about the centre of gravity, its Jacobian against
  central differences;
* an identification whose unconstrained optimum is not physical (synthetic trials of a body whose pitch
  inertia breaks the triangle inequality: no model it can load can fit them exactly): without the
  parameterisation the estimate is refused by the loader, with it the written file loads;
* SIGTERM and SIGHUP during the optimisation: one line, non-zero exit, an existing file untouched;
* relative thrust-table paths and long names in the identified file.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tomlkit

import arvcas
from arvcas.cli import main
from arvcas.ident import identify as ident_mod
from arvcas.ident import logs, physical, synthetic
from arvcas.ident.estimate import identified_name, writable
from arvcas.util import files
from arvcas.system import System
from arvcas.system.params import ParamsError, check_physical
from ident_helpers import armless

PRINCIPAL = ("vehicle.Ixx", "vehicle.Iyy", "vehicle.Izz")
# the Hinsdale vehicle's Ixx + Izz is 0.691 kg m^2: a pitch inertia of 0.9 is no mass distribution's
BROKEN = {"vehicle.Iyy": 0.9}


@pytest.fixture(scope="module")
def vehicle(tmp_path_factory):
    """The Hinsdale vehicle without its arm (as tests/test_identify.py), and a 'truth' no physical body has."""
    d = tmp_path_factory.mktemp("vehicle")
    model = arvcas.load_system(armless("hinsdale_bluerov2_alpha5", d, "hinsdale_vehicle"))
    truth = System(model.params.replace(BROKEN))
    with pytest.raises(ParamsError, match="triangle inequality"):
        check_physical(truth.params.as_dict(), "truth", truth.layout)
    trials = [synthetic.write_trial(d / "logs", f"b{k}", truth, duration=6.0, seed=k, p=truth.params.vector())
              for k in (0, 1)]
    return model, trials


def _values(system, free, theta) -> dict:
    v = system.params.as_dict()
    v.update(zip(free, map(float, theta)))
    return v


def _inertia_about_cg(v: dict) -> np.ndarray:
    T = np.array([[v["vehicle.Ixx"], -v["vehicle.Ixy"], -v["vehicle.Ixz"]],
                  [-v["vehicle.Ixy"], v["vehicle.Iyy"], -v["vehicle.Iyz"]],
                  [-v["vehicle.Ixz"], -v["vehicle.Iyz"], v["vehicle.Izz"]]])
    r = np.array([v["vehicle.xG"], v["vehicle.yG"], v["vehicle.zG"]])
    return T - v["vehicle.m"] * (r @ r * np.eye(3) - np.outer(r, r))  # parallel axes


@pytest.mark.parametrize("free", [PRINCIPAL, PRINCIPAL + ("vehicle.Ixy", "vehicle.zG"),
                                  ("vehicle.m",) + PRINCIPAL + ("vehicle.Ixz", "vehicle.Iyz", "vehicle.xG")])
def test_rigid_body_map_stays_physical(vehicle, free):
    model = vehicle[0]
    mp = physical.Mapping(model.layout, free, model.params.vector())
    assert mp.groups and np.allclose(mp.theta(np.zeros(len(free))), mp.theta0, rtol=1e-14, atol=1e-15)
    rng = np.random.default_rng(3)
    for _ in range(200):
        v = rng.normal(0, 2.0, len(free))
        vals = _values(model, free, mp.theta(v))
        lam = np.linalg.eigvalsh(_inertia_about_cg(vals))
        assert lam[0] > 0 and lam[0] + lam[1] >= lam[2] * (1 - 1e-9), lam  # a mass distribution has them
        for n in model.layout.names:  # the products not freed keep their file values
            if n.startswith("vehicle.I") and n not in free:
                assert vals[n] == model.params[n]
        check_physical(vals, "mapped", model.layout)  # the loader's own rules
    v = rng.normal(0, 1.0, len(free))
    J = mp.jacobian(v)
    eye = np.eye(len(free))
    fd = np.array([(mp.theta(v + 1e-6 * eye[k]) - mp.theta(v - 1e-6 * eye[k])) / 2e-6 for k in range(len(free))]).T
    assert np.max(np.abs(J - fd)) <= 1e-6 * np.max(np.abs(fd))


@pytest.mark.parametrize("free", [("arm.link2.inertia.ixx", "arm.link2.inertia.iyy", "arm.link2.inertia.izz"),
                                  ("arm.link3.inertia.ixx", "arm.link3.inertia.iyy", "arm.link3.inertia.izz",
                                   "arm.link3.inertia.ixz", "arm.link3.mass")])
def test_link_inertia_map_stays_physical(free):
    """A chain-form link's inertia (URDF signs, about its centre of mass): every value passes the loader's
    link checks; the triangle inequality by NumPy's eigenvalues."""
    system = arvcas.load_system("bluerov2_heavy_alpha5")
    mp = physical.Mapping(system.layout, free, system.params.vector())
    assert len(mp.groups) == 1 and mp.groups[0].startswith("arm link")
    assert np.allclose(mp.theta(np.zeros(len(free))), mp.theta0, rtol=1e-13, atol=1e-16)
    rng = np.random.default_rng(7)
    k = free[0].rsplit(".", 1)[0]
    for trial in range(200):
        vals = _values(system, free, mp.theta(rng.normal(0, 2.0, len(free))))
        I = np.array([[vals[f"{k}.ixx"], vals[f"{k}.ixy"], vals[f"{k}.ixz"]],
                      [vals[f"{k}.ixy"], vals[f"{k}.iyy"], vals[f"{k}.iyz"]],
                      [vals[f"{k}.ixz"], vals[f"{k}.iyz"], vals[f"{k}.izz"]]])
        lam = np.linalg.eigvalsh(I)
        assert lam[0] > 0 and lam[0] + lam[1] >= lam[2] * (1 - 1e-9), lam
        if trial < 2:  # the loader's own rules (2 s each for this system)
            check_physical(vals, "mapped", system.layout)
    unmapped = physical.Mapping(system.layout, free, system.params.vector(), factors=False)
    v = np.zeros(len(free))
    v[1] = 20.0  # iyy 21 times its value: beyond ixx + izz without the factor
    with pytest.raises(ParamsError, match="link 2's inertia tensor|link 3's inertia tensor"):
        check_physical(_values(system, free, unmapped.theta(v)), "unmapped", system.layout)


@pytest.mark.parametrize("free", [("hydro.X_u", "hydro.Y_v", "hydro.X_v", "hydro.Y_u"),
                                  ("hydro.X_udot", "hydro.Y_vdot", "hydro.X_vdot"), ("hydro.Y_v", "hydro.X_v"),
                                  ("hydro.X_u", "hydro.N_r", "hydro.N_v", "hydro.Y_v", "hydro.K_p")])
def test_hydrodynamic_matrix_maps_stay_positive(free):
    """Haidou-1's coupled added mass and linear damping (Table A1): with off-diagonal terms free, the symmetric
    part of each matrix stays positive semi-definite (NumPy's eigenvalues) and the held terms keep their values."""
    system = arvcas.load_system("haidou1")
    lay = system.layout
    mp = physical.Mapping(lay, free, system.params.vector())
    assert len(mp.groups) == 1 and not mp.notes
    assert np.allclose(mp.theta(np.zeros(len(free))), mp.theta0, rtol=1e-14, atol=1e-15)
    rng = np.random.default_rng(5)
    base = physical._matrices(system.params.as_dict(), lay)
    for _ in range(200):
        vals = _values(system, free, mp.theta(rng.normal(0, 2.0, len(free))))
        for A, A0 in zip(physical._matrices(vals, lay), base):
            S = 0.5 * (A + A.T)
            assert np.linalg.eigvalsh(S)[0] >= -1e-12 * np.abs(S).max()
        for n in lay.names:
            if n.startswith("hydro.") and n not in free:
                assert vals[n] == system.params[n]
    v = rng.normal(0, 1.0, len(free))
    eye = np.eye(len(free))
    fd = np.array([(mp.theta(v + 1e-6 * eye[k]) - mp.theta(v - 1e-6 * eye[k])) / 2e-6 for k in range(len(free))]).T
    assert np.max(np.abs(mp.jacobian(v) - fd)) <= 1e-6 * np.max(np.abs(fd))
    # the edge of the set is flagged: a diagonal factor near zero, a nearly singular symmetric part
    assert mp.edge(system.params.as_dict()) == []
    v = np.zeros(len(free))
    v[0] = -8.0
    assert set(mp.edge(_values(system, free, mp.theta(v)))) == set(free)
    # without a factor the same terms can leave the set: a unit step of X_v alone makes the damping indefinite
    raw = physical.Mapping(lay, free, system.params.vector(), factors=False)
    k = free.index("hydro.X_v") if "hydro.X_v" in free else None
    if k is not None:
        v = np.zeros(len(free))
        v[k] = 2000.0
        D = physical._matrices(_values(system, free, raw.theta(v)), lay)[1]
        assert np.linalg.eigvalsh(0.5 * (D + D.T))[0] < 0


def test_a_held_member_leaves_its_group(vehicle):
    """A group member the trials carry no information about is held: the group forms without it (a principal
    moment held: the others by their bounds; a product held: it keeps its value through the factor)."""
    model = vehicle[0]
    p = model.params.vector()
    free = PRINCIPAL + ("vehicle.Ixy",)
    assert physical.Mapping(model.layout, free, p, held=("vehicle.Izz",)).groups == []
    mp = physical.Mapping(model.layout, free, p, held=("vehicle.Ixy",))
    assert len(mp.groups) == 1 and "vehicle.Ixy" not in mp.mapped
    th = mp.theta(np.array([0.3, -0.2, 0.1, 0.0]))
    assert th[3] == model.params["vehicle.Ixy"] and th[0] != model.params["vehicle.Ixx"]


def test_nonphysical_optimum_still_writes_a_file_that_loads(vehicle, tmp_path, capfd):
    model, trials = vehicle
    lg = logs.load_logs(trials, n_joints=0)
    free = PRINCIPAL
    raw = ident_mod.identify(model, lg, free, threads=1, physical_set=False)
    with pytest.raises(ParamsError, match="triangle inequality"):  # the unconstrained optimum: no body has it
        check_physical(_values(model, free, raw.values), "unconstrained", model.layout)
    assert raw.values[1] > 0.8, raw.report()  # it found the truth's pitch inertia
    out = tmp_path / "elsewhere" / "identified.toml"
    # the fit creeps along the edge of the physical set (62 iterations to converge); 12 suffice here: every
    # iterate is physical
    rc = main(["identify", "--system", model.path, "--free", ",".join(free), *map(str, trials), "--out", str(out),
               "--threads", "1", "--max-iter", "12"])
    text, err = capfd.readouterr()
    assert rc == 0, text
    assert "physical parameterisation: vehicle rigid body" in text and "stopped at the iteration cap (12)" in text
    # IPOPT tried steps at which the simulation diverged (4 here): one line with the count, no CasADi warnings
    assert "NaN detected" not in text + err and "WARNING" not in text + err, err
    assert text.count("evaluations of the simulation were not finite") == 1, text
    ident = arvcas.load_system(out)  # the normal loader
    lam = np.linalg.eigvalsh(_inertia_about_cg(ident.params.as_dict()))
    assert lam[0] + lam[1] >= lam[2] * (1 - 1e-9)
    assert ident.params["vehicle.Iyy"] > model.params["vehicle.Iyy"]  # it moved towards the data
    # a principal moment freed alone is bounded by the others: the estimate is held where the file loads
    one = ident_mod.identify(model, lg, ("vehicle.Iyy",), threads=1)
    assert one.pulled is not None and "triangle inequality" in one.pulled[1], one.report()
    check_physical(_values(model, ("vehicle.Iyy",), one.values), "held", model.layout)
    assert "held at" in one.report() and one.values[0] > model.params["vehicle.Iyy"]
    assert one.at_bound == ("vehicle.Iyy",) and "ended at the edge of its physical set" in one.report()


def test_iteration_cap_and_flags_in_the_report(vehicle):
    model, trials = vehicle
    est = ident_mod.identify(model, logs.load_logs(trials[:1], n_joints=0), PRINCIPAL, threads=1, max_iter=2)
    rep = est.report()
    assert est.status == "Maximum_Iterations_Exceeded" and math.isfinite(est.inf_du)
    assert "stopped at the iteration cap (2)" in rep and f"{est.inf_du:.3g}" in rep and "--max-iter" in rep
    moved = ident_mod.Estimate(**{**est.__dict__, "values": est.initial * np.array([1.0, 4.0, 0.2]),
                                  "at_bound": ()})
    names = [n for n, _ in moved.flags()]
    assert names == ["vehicle.Iyy", "vehicle.Izz"] and "absorbs something the model lacks" in moved.report()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_terminated_identification_writes_nothing(vehicle, tmp_path, sig):
    model, trials = vehicle
    out = tmp_path / "id.toml"
    files.write_text(out, "# an identified file from an earlier run\n")
    before = out.read_bytes()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(arvcas.__file__).parents[1]),
                                                       os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-m", "arvcas.cli", "identify", "--system", str(model.path), "--free",
                             ",".join(PRINCIPAL), *map(str, trials), "--out", str(out), "--threads", "1",
                             "--max-iter", "500"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    for line in proc.stdout:
        if line.startswith("iteration   1"):
            proc.send_signal(sig)
            break
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 128 + sig, err
    assert err == f"arvcas: terminated ({signal.Signals(sig).name})\n", err
    assert out.read_bytes() == before


def _estimate(system, free, values):
    n = len(free)
    return ident_mod.Estimate(system=system, free=tuple(free), initial=np.array([system.params[k] for k in free]),
                              values=np.array(values, dtype=float), std=np.full(n, 0.01), correlation=np.eye(n),
                              identifiable=np.ones(n, dtype=bool), unidentifiable=(), correlated=(), trials=("t",),
                              signals=("roll",), sigma={"roll": 0.01}, x0={}, cost0=1.0, cost=0.5, s2=1.0,
                              n_residuals=100, status="Solve_Succeeded", iterations=3, seconds=1.0, h=0.02)


@pytest.mark.floor  # the identified file written with tomlkit at its floor
def test_identified_file_loads_from_another_folder_with_a_long_name(tmp_path):
    """A system whose thrust table is a relative path beside it, identified into another folder, with a name
    of the loader's longest length."""
    rov = arvcas.load_system("bluerov2_heavy_alpha5")
    (tmp_path / "sys" / "tables").mkdir(parents=True)
    doc = tomlkit.parse(armless("bluerov2_heavy_alpha5", tmp_path / "sys", "r" * 64).read_text(encoding="utf-8"))
    table = Path(rov.path).parent / doc["thrusters"]["map"]["t200_16v"]["table"]
    (tmp_path / "sys" / "tables" / "mine.csv").write_text(table.read_text(encoding="utf-8"), encoding="utf-8")
    doc["thrusters"]["map"]["t200_16v"]["table"] = "tables/mine.csv"
    src = tmp_path / "sys" / "rov.toml"
    src.write_text(tomlkit.dumps(doc), encoding="utf-8")
    system = arvcas.load_system(src)
    est = _estimate(system, ("hydro.X_u",), [1.5 * system.params["hydro.X_u"]])
    out = tmp_path / "elsewhere" / "deeper" / "rov_identified.toml"
    out.parent.mkdir(parents=True)
    out.write_text(est.system_text(out), encoding="utf-8")
    ident = arvcas.load_system(out)
    assert ident.params["hydro.X_u"] == pytest.approx(1.5 * system.params["hydro.X_u"])
    assert len(ident.name) == 64 and ident.name.endswith("_identified") and ident.name.startswith("rrr")
    assert identified_name(ident.name) == ident.name
    assert "../../sys/tables/mine.csv" in out.read_text(encoding="utf-8")
    with pytest.raises(ident_mod.IdentifyError, match="free: thrusters.T1.direction.x is an element of a unit"):
        ident_mod.identify(system, [], ("thrusters.T1.direction.x",))
    # a table file's points are not rewritten: refused before any work, naming the file
    with pytest.raises(ident_mod.IdentifyError, match="thrusters.map.t200_16v.thrust.3 comes from the thrust "
                                                      "table file 'tables/mine.csv'"):
        writable(system, ("thrusters.map.t200_16v.thrust.3",))


def test_identified_urdf_system_loads_from_another_folder(tmp_path):
    """A system whose arm is a URDF at a relative path (a subfolder), identified into another folder."""
    pytest.importorskip("pinocchio")
    import urdf_arms as ua

    dh = arvcas.load_system("haidou1")
    v = dict(zip(dh.params.names(), np.asarray(dh.params.vector(), float)))
    (tmp_path / "sys" / "arm").mkdir(parents=True)
    (tmp_path / "sys" / "arm" / "haidou1_arm.urdf").write_text(ua.haidou1_urdf(v), encoding="utf-8")
    src = tmp_path / "sys" / "haidou1_urdf.toml"
    src.write_text(ua.haidou1_form3_toml(ua.shipped_haidou1_text(), v, urdf_name="arm/haidou1_arm.urdf"),
                   encoding="utf-8")
    system = arvcas.load_system(src)
    est = _estimate(system, ("hydro.X_u",), [1.5 * system.params["hydro.X_u"]])
    out = tmp_path / "other" / "haidou1_identified.toml"
    out.parent.mkdir()
    out.write_text(est.system_text(out), encoding="utf-8")
    ident = arvcas.load_system(out)
    assert ident.params["hydro.X_u"] == pytest.approx(1.5 * system.params["hydro.X_u"])
    assert ident.n_joints == 6 and 'urdf = "../sys/arm/haidou1_arm.urdf"' in out.read_text(encoding="utf-8")
