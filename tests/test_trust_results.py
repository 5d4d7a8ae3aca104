"""No wrong result in silence: a neutrally buoyant arm has a finite trim, an arm motion shorter than the
plant step is refused, seeds are exact in .mat files (above 2**53 too), a cold build beside a read-only
cache builds outside it, and a run that stops names why."""

from __future__ import annotations

import errno
import os
import re
import shutil
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import arvcas
from arvcas.sim.scenario import ScenarioError, load_scenario
from arvcas.system import shipped

from trust_helpers import scenario_variant


def _neutral_arm(d: Path) -> Path:
    """The shipped BlueROV2 with every arm link of 1 kg and 1 L in fresh water: the arm's static weight in
    water is exactly zero (a pure couple remains, the links' centres of buoyancy and mass differ)."""
    src = shipped()["bluerov2_heavy_alpha5"]
    for f in src.parent.glob("bluerov2_heavy_alpha5.*toml"):
        shutil.copy(f, d / f.name)

    def neutral(m):
        block = re.sub(r"^mass = \{ value = [^,]+,", "mass = { value = 1.0,", m.group(0), flags=re.M)
        return re.sub(r"^volume = \{ value = [^,]+,", "volume = { value = 0.001,", block, flags=re.M)

    (d / src.name).write_text(re.sub(r"\[arm\.link\d\][\s\S]*?(?=\n\[)", neutral, src.read_text()))
    return d / src.name


def test_a_neutrally_buoyant_arm_has_a_finite_trim(tmp_path):
    from arvcas.model import manipulator
    from arvcas.system.params import load, view

    path = _neutral_arm(tmp_path)
    P = load(path)
    Fz, Mx, My = (float(v) for v in manipulator.trim_static(view(P.vector(), P.layout)))
    assert Fz == 0.0 and abs(My) > 1e-3  # no weight in water, a couple: the trim's old division was 0/0
    level = np.array(manipulator.trim_from_static(Fz, Mx, My, ca.DM.zeros(6)), dtype=float).ravel()
    np.testing.assert_allclose(level, [0, 0, 0, -Mx, -My, 0], atol=1e-15)  # it cancels the couple, as any trim
    tilted = np.array(manipulator.trim_from_static(Fz, Mx, My, ca.DM([0, 0, 0, 0.1, -0.2, 0.3])), dtype=float)
    assert np.isfinite(tilted).all()
    f = arvcas.dynamics("uvms_rhs", system=path)
    xdot = f(np.zeros(12), np.zeros(6), np.zeros(4), np.zeros(4), np.zeros(4), 0.0)
    assert np.isfinite(xdot).all()
    r = arvcas.Run("pid", system=str(path)).compile().simulate(seed=0)
    assert r.ok or r.t_fail > 0, r  # every run "diverged at t = 0" with NaN accelerations
    assert np.isfinite(r.chat).all() and np.isfinite(r.eta).all()


def test_an_arm_motion_shorter_than_the_plant_step_is_refused(tmp_path):
    """A reach of 1 ms (the plant step is 10 ms): between two RK4 stage times, the arm would jump with no
    reaction on the vehicle."""
    p = scenario_variant(tmp_path, 't = { value = 19.0, unit = "s"', 't = { value = 5.001, unit = "s"')
    with pytest.raises(ScenarioError, match=r"arm.waypoint\[2\].t: the motion from waypoint 1 takes 0.001 s, less "
                                            r"than the plant step time.h_plant \(0.01 s\)") as e:
        load_scenario(p)
    assert "\n" not in str(e.value)


def test_seeds_are_exact_in_mat_files(tmp_path):
    from scipy.io import loadmat

    from arvcas.io.matfile import write_result_mat

    seed = 2**53 + 1  # float(seed) == 2**53
    r = arvcas.simulate("pid", seed=seed, system=arvcas.load_system("bluerov2_heavy_alpha5").params)
    m = loadmat(write_result_mat(r, tmp_path / "r.mat"), simplify_cells=True)
    assert int(m["seed"]) == seed
    names = list(m["param_names"])  # the BlueROV2's, not Haidou-1's
    assert len(names) == len(r.params_vector) and "thrusters.T1.u_max" in names


def test_a_cold_build_beside_a_read_only_cache_builds_outside_it(tmp_path, monkeypatch):
    from arvcas.build import codegen

    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    monkeypatch.setenv("ARVCAS_CACHE", str(cache))
    real_open, real_mkdir = os.open, os.mkdir

    def ro(path):
        return str(path).startswith(str(cache) + os.sep)

    def no_create(p, flags, *a, **k):  # a read-only file system under the cache (root would bypass chmod)
        if ro(p) and flags & (os.O_CREAT | os.O_WRONLY | os.O_RDWR):
            raise OSError(errno.EROFS, "Read-only file system", str(p))
        return real_open(p, flags, *a, **k)

    def no_mkdir(p, *a, **k):
        if ro(p):
            raise OSError(errno.EROFS, "Read-only file system", str(p))
        return real_mkdir(p, *a, **k)

    monkeypatch.setattr(os, "open", no_create)
    monkeypatch.setattr(os, "mkdir", no_mkdir)
    x = ca.SX.sym("x")
    f = codegen.build(ca.Function("trust_ro_square", [x], [x * x + 0.25]))
    assert float(f(3.0)) == 9.25
    lib = Path(codegen.artifact_of(f)["path"])
    assert lib.is_relative_to(tempfile.gettempdir()) and "arvcas-private-" in str(lib)
    assert list(cache.iterdir()) == []


def test_a_run_that_stops_names_why(capsys):
    from arvcas.system.params import load

    P = load().replace({"env.rho": 1e300})  # no finite motion: Params.replace skips the physical checks
    r = arvcas.Run("pid", system=P).compile().simulate(seed=0)
    assert not r.ok and "not finite" in r.meta["failure"] and "not finite" in repr(r)
