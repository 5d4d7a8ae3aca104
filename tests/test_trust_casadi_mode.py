"""CasADi 3.8's NumPy mode (CasADi issue #2959): arvcas never calls a NumPy function on a CasADi value, so
it gives the same numbers, and no FutureWarning, in every mode (1: casadi-aware, 0: legacy with the
warning, -1: legacy, silent); the command line chooses its mode (-1) explicitly and restores the caller's."""

from __future__ import annotations

import warnings

import casadi as ca
import numpy as np
import pytest

import arvcas

MODES = (1, 0, -1)


def _numbers() -> dict[str, np.ndarray]:
    """What the main paths compute: systems loaded and checked, the trim, the time table, a run, the
    plant functions from NumPy, the FMU's variables and the demo's table."""
    from arvcas import cli
    from arvcas.build import fmu
    from arvcas.model import manipulator
    from arvcas.system.params import view
    from arvcas.sim import profiles, scenario

    out = {}
    for name in ("haidou1", "bluerov2_heavy_alpha5"):
        s = arvcas.load_system(name)
        P = view(s.params.vector(), s.layout)
        out[f"{name} trim"] = np.array([float(v) for v in manipulator.trim_static(P)])
        cfg = scenario.load_scenario(s.params.default("scenario"))
        t = ca.SX.sym("t")
        fq = ca.Function("q", [t], list(profiles.joint_trajectory(cfg, manipulator.stow_pose(P), t)))
        out[f"{name} q(7 s)"] = np.concatenate([np.asarray(v, dtype=float).ravel() for v in fq(7.0)])
        out[f"{name} starts"] = np.array([v["start"] for v in fmu.variables(s.params)], dtype=float)
    r = arvcas.Run("pid").compile().simulate(seed=1)
    out["run"] = np.concatenate([r.chat, r.rmse, r.eta[-1]])
    f = arvcas.dynamics("uvms_rhs")
    out["uvms_rhs"] = f(np.full(12, 0.1), np.ones(6), np.zeros(6), np.zeros(6), np.zeros(6), 0.5)
    out["demo"] = np.array(cli.demo_table(t_end=6.0, dt=3.0), dtype=float)
    return out


@pytest.fixture()
def mode():
    get = getattr(ca.GlobalOptions, "getNumpyMode", None)
    if get is None:
        pytest.skip("this CasADi has no NumPy mode (before 3.8)")
    before = get()
    yield ca.GlobalOptions.setNumpyMode
    ca.GlobalOptions.setNumpyMode(before)


def test_the_same_numbers_and_no_warning_in_every_numpy_mode(mode):
    got = {}
    for m in MODES:
        mode(m)
        with warnings.catch_warnings():
            warnings.simplefilter("error", FutureWarning)
            got[m] = _numbers()
    for m in MODES[1:]:
        for k, v in got[MODES[0]].items():
            np.testing.assert_array_equal(got[m][k], v, err_msg=f"mode {m}: {k}")


def test_the_command_line_chooses_its_mode_explicitly(mode, capsys, monkeypatch):
    import dataclasses

    from arvcas import cli

    seen = []
    cmd = cli.COMMANDS["systems"]
    monkeypatch.setitem(cli.COMMANDS, "systems", dataclasses.replace(
        cmd, run=lambda a: seen.append(ca.GlobalOptions.getNumpyMode()) or cmd.run(a)))
    mode(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FutureWarning)
        assert cli.main(["systems"]) == 0
    assert seen == [-1] and ca.GlobalOptions.getNumpyMode() == 0  # chosen for the command, then restored
