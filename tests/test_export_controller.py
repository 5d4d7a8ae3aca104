"""``arvcas export-controller``: the exported controller is the run's controller.

For the proposed law, AGSTA and PID on Haidou-1 and the BlueROV2 Heavy + Alpha 5 (the shipped systems
with a scenario and gains of their own; hinsdale_bluerov2_alpha5 is for validation only): the package is written by the command
line and built by its own Makefile (library, C and C++ examples: the header compiles as C and as
C++); closed through its ctypes binding around the plant's compiled C (``uvms_rhs``, ``thrust``: the
code ``arvcas export-c`` writes) over the run's scenario (its noise sequence, its time table), it
reproduces arvcas's compiled run, trace and metrics, to 1e-12 (the plant's C computes the arm's terms
directly, the run from its time table: round-off apart); fed the run's own measurements it returns
the run's commands bit for bit. The runs reused are those other test files compile (Haidou-1's 100 s
default; the BlueROV2's default cut to 20 s, as tests/test_systems.py and tests/test_system_study.py).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

import arvcas
from arvcas import cli
from arvcas.controllers import gains as gains_mod
from arvcas.sim import scenario
from arvcas.export.closeloop import close_loop, load_binding
from arvcas.export.controller import default_prefix, files
from arvcas.system import load_system
from arvcas.tuning.front import read_front

from trust_helpers import synthetic_front
from make_helpers import make_cmd

LAWS = ("proposed", "agsta", "pid")
SYSTEMS = ("haidou1", "bluerov2_heavy_alpha5")  # the shipped systems with a scenario and gains of their own
SEED = 3
TOL = 1e-12
# what was measured, printed at the end of the module (pytest -s) for the report
MEASURED: dict = {}


def _cfg(s):
    """The system's scenario; the BlueROV2's with its T200 dynamics (the rotors in close_loop) and its tether's
    pull, without its current (the exported plant the controller is closed around, export-c's uvms_rhs, takes a
    body wrench: the relative-velocity current acts inside its hydrodynamics, and without it the tether has no
    drag; docs/exporting-a-controller.md) and with plain RK4 at its 0.01 s step in place of its thrust quadrature
    (close_loop integrates the exported plant by RK4 with the thrust at the stage times)."""
    cfg = scenario.load_scenario(s.params.default("scenario"))
    if s.name == "haidou1":
        return cfg
    assert cfg.has_tether and cfg.current == "constant"
    assert cfg.time_thrust_quadrature
    return replace(cfg, time_duration=20.0, current_velocity=None, time_thrust_quadrature=None)


def _run(cmd, **kw):
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, **kw)
    assert r.returncode == 0, f"{cmd}: {r.stdout[-2000:]} {r.stderr[-2000:]}"
    return r.stdout


@pytest.fixture(scope="module", params=[(s, law) for s in SYSTEMS for law in LAWS], ids=lambda c: f"{c[0]}-{c[1]}")
def case(request, tmp_path_factory):
    """(system, law, export dir, binding module, controller, compiled run, the run's result)."""
    if shutil.which("make") is None or shutil.which("c++") is None:
        pytest.skip("make or c++ is not installed")
    name, law = request.param
    s = load_system(name)
    cfg = _cfg(s)
    d = tmp_path_factory.mktemp(f"ctl_{name}_{law}")
    argv = ["export-controller", str(d / "out"), "--controller", law, "--system", name]
    if name != "haidou1":
        (d / "scenario.toml").write_text(cfg.to_toml(), encoding="utf-8")
        argv += ["--config", str(d / "scenario.toml")]
    assert cli.main(argv) == 0
    out = d / "out"
    _run(make_cmd(out))
    mod, ctl = load_binding(out)
    run = arvcas.Run(law, scenario=cfg, system=s.params).compile()
    return name, law, out, mod, ctl, run, run.simulate(seed=SEED)


def test_closed_loop_reproduces_the_run(case):
    """Exported controller + the plant's C over the run's scenario = the compiled run, to 1e-12."""
    name, law, _, _, ctl, run, r = case
    e = close_loop(ctl, run, seed=SEED)
    compared = [k for k in e if k in r.series]
    assert set(r.series) - set(compared) == {"f_true"}  # the plant's truth, not the controller's
    worst = {}
    for k in compared:
        a, b = e[k].reshape(r.series[k].shape), r.series[k]
        diff = np.abs(a - b).max()
        scale = max(1.0, np.abs(b).max())
        worst[k] = diff
        assert diff <= TOL * scale, f"{name}/{law} {k}: max |difference| {diff:.3g} (scale {scale:.3g})"
    for k in ("chat", "rmse", "chat_delivered"):
        np.testing.assert_allclose(e[k], getattr(r, k), rtol=TOL, atol=0)
        worst[k + "_rel"] = float(np.max(np.abs(e[k] - getattr(r, k)) / np.abs(getattr(r, k))))
    assert r.ok and np.abs(r.q - r.q[0]).max() > 0.1  # the arm moved: the coupling is exercised
    MEASURED[(name, law)] = worst


def test_replay_is_bit_for_bit(case):
    """Fed the run's own measurements (true states + the same noise), the controller returns the run's
    estimate, reference, commands and law signals bit for bit."""
    name, law, _, mod, ctl, run, r = case
    dyn = run.params.structure.has_thruster_dynamics
    e = close_loop(ctl, run, seed=SEED, states=np.hstack([r.eta, r.nu]), delivered=r.thrust if dyn else None)
    sent = ["thrust_cmd", "command"] if dyn else ["thrust"]  # the controller's thrust (and command)
    names = [n for n, *_ in mod.DIAGNOSTICS if n in r.series] + sent
    assert {"eta_hat", "eta_ref", "tau_cmd"} <= set(names) and set(ctl.diagnostics()) >= set(names) - set(sent)
    assert dyn == (name == "bluerov2_heavy_alpha5") == mod.HAS_COMMAND_MAP
    for k in names:
        np.testing.assert_array_equal(e[k].reshape(r.series[k].shape), r.series[k], err_msg=f"{name}/{law} {k}")


def test_examples_print_the_same_and_header_is_c_and_cpp(case):
    """make built example (C) and example_cpp (C++) against the header; both and example.py (ctypes)
    print the same lines; the header alone compiles as strict C99 and C++11."""
    name, law, out, mod, ctl, *_ = case
    c = _run([str(out / "example")], cwd="/")
    assert c == _run([str(out / "example_cpp")], cwd="/") == _run([sys.executable, str(out / "example.py")],
                                                                     cwd=str(out))
    assert c.count("\nstep ") + c.startswith("step ") == 5
    lib = default_prefix(name, law).rstrip("_")
    for cc, std in (("cc", "-std=c99"), ("c++", "-std=c++11")):
        lang = "c" if cc == "cc" else "c++"
        _run([cc, std, "-Wall", "-Wextra", "-pedantic", "-Werror", "-fsyntax-only", "-x", lang, str(out / f"{lib}.h")])


def test_symbols_carry_the_prefix_and_no_heap(case):
    name, law, out, *_ = case
    prefix = default_prefix(name, law)
    nm = _run(["nm", "-D", "--defined-only", str(out / f"lib{prefix.rstrip('_')}.so")])
    syms = [ln.split()[-1] for ln in nm.splitlines() if ln.split() and ln.split()[-2] in ("T", "D", "B", "R")]
    assert syms and all(s.startswith(prefix) for s in syms), [s for s in syms if not s.startswith(prefix)]
    und = _run(["nm", "-D", "--undefined-only", str(out / f"lib{prefix.rstrip('_')}.so")])
    assert not any(f in und.split() for f in ("malloc", "calloc", "realloc", "free"))
    # no writable data of its own (the toolchain's start-up objects have some: _DYNAMIC, completed.0, ...)
    every = _run(["nm", "--defined-only", str(out / f"lib{prefix.rstrip('_')}.so")])
    data = [ln.split()[-1] for ln in every.splitlines() if len(ln.split()) == 3 and ln.split()[1] in "dDbB"]
    assert data and not [d for d in data if d.startswith((prefix, "casadi"))]


@pytest.mark.parametrize("case", [("haidou1", "proposed")], indirect=True, ids=["haidou1-proposed"])
def test_gains_as_inputs_reset_and_errors(case):
    """Other gains through init replay the run with those gains bit for bit; reset gives a fresh start;
    bad gains, parameters and measurements are refused with the state unchanged (on one case: the code
    is the same for every law and system; Haidou-1's thrusters have no command map)."""
    name, law, _, mod, ctl, run, r = case
    g = gains_mod.default_gains(law) * 1.1
    r2 = run.simulate(gains=g, seed=SEED)
    ctl.init(gains=g)
    e = close_loop(ctl, run, seed=SEED, states=np.hstack([r2.eta, r2.nu]))
    np.testing.assert_array_equal(e["tau_cmd"], r2.tau_cmd)
    y = list(r.eta[0]) + list(r.nu[0])
    ctl.reset()
    first = ctl.step(y, 0.0)
    for k in range(1, 4):
        ctl.step(y, k * 0.1)
    ctl.reset()
    assert ctl.step(y, 0.0) == first
    names = gains_mod.gain_names(law)
    h = run.cfg.time_h
    for i, v in ((0, 0.0), (1, float("nan")), (names.index("x.omega"), 2.0 / h)):
        bad = list(g)
        bad[i] = v
        with pytest.raises(mod.ControllerError, match=rf"a gain is not finite.*: gains\[{i}\]$"):
            ctl.init(gains=bad)
    with pytest.raises(mod.ControllerError, match=r"ekf q < 0 or variance <= 0.*: ekf\[2\]$"):
        ctl.init(gains=g, ekf=[1e-6, 1e-6, 0.0, 1e-4, 1e-4])
    with pytest.raises(mod.ControllerError, match="no command map"):
        ctl.command()  # Haidou-1's thrusters have no command map
    with pytest.raises(mod.ControllerError, match="init: eta_d: expected 6 values"):
        ctl.init(eta_d=[0.0])
    ctl.step(y, 0.0)  # the refused inits changed nothing: still initialised with g
    assert list(ctl.params.gains) == list(g)
    with pytest.raises(mod.ControllerError, match=r"impossible.*: p\[0\]$"):
        ctl.init(p=[0.0] * len(ctl.params.p))  # no water (env.rho = 0): the sign rules first
    names_p = arvcas.load_system(name).params.layout.names
    p_flat = [0.0 if n.startswith("thrusters.") else v for n, v in zip(names_p, ctl.defaults()["p"])]
    with pytest.raises(mod.ControllerError, match="not finite.*: derived terms$"):
        ctl.init(p=p_flat)  # every rule holds, but no thruster matrix to invert
    with pytest.raises(mod.ControllerError, match="not initialised"):
        ctl.step(y, 0.0)
    ctl.init(**ctl.defaults())
    a = [ctl.step(y, 0.0), ctl.step(y, 0.1)]
    ctl.reset()
    ctl.step(y, 0.0)
    with pytest.raises(mod.ControllerError, match="y, t or tau_arm is not finite"):
        ctl.step([float("nan")] + y[1:], 0.1)
    assert ctl.step(y, 0.1) == a[1]  # the refused step changed nothing
    ctl.init(**ctl.defaults())


def test_cli_front_member_knee_and_index(tmp_path, capsys):
    """--front F --member knee|INDEX: the member's gains become the defaults; the front's controller."""
    front = synthetic_front(tmp_path / "front.h5", controller="pid")
    fr = read_front(front)
    for member, k in (("knee", fr.knee()), ("2", 2), ("-1", fr.size - 1)):
        out = tmp_path / f"m{member}"
        assert cli.main(["export-controller", str(out), "--front", str(front), "--member", member]) == 0
        assert "gains: member" in capsys.readouterr().out
        text = (out / "arvcas_haidou1_pid.c").read_text()
        want = ", ".join(repr(float(x)) for x in fr.gains[k])
        assert f"static const double gains[{fr.gains.shape[1]}] = {{{want}}};" in text
        assert f"member {k} of the {fr.size} of the front" in (out / "README.md").read_text()
    assert fr.knee() == 1  # the balanced member of the synthetic front


def test_cli_refusals(tmp_path, capsys):
    front = synthetic_front(tmp_path / "front.h5", controller="agsta")
    other = synthetic_front(tmp_path / "old.h5", controller="agsta", model_hash="0" * 64)
    cases = [
        (["--controller", "pid", "--member", "knee"], "--member: only with --front"),
        ([], "--controller: required unless --front"),
        (["--front", str(front)], "--front needs --member knee|INDEX"),
        (["--front", str(front), "--member", "3"], "--member 3: "),
        (["--front", str(front), "--member", "kne"], "expected knee or an integer member index"),
        (["--front", str(front), "--member", "knee", "--controller", "pid"], "differs from the front's controller agsta"),
        (["--front", str(other), "--member", "knee"], "--allow-model-change"),
        (["--controller", "nope"], "unknown 'nope'"),
        (["--controller", "pid", "--prefix", "9bad_"], "prefix: expected a C identifier"),
        (["--controller", "pid", "--system", "hinsdale_bluerov2_alpha5"], "names no default scenario"),
    ]
    for args, msg in cases:
        assert cli.main(["export-controller", str(tmp_path / "x"), *args]) == 2
        err = capsys.readouterr().err
        assert err.startswith("arvcas: error:") and msg in err and err.count("\n") == 1, (args, err)
    assert not (tmp_path / "x").exists()
    # a file arvcas did not write is not replaced; --force replaces it; a re-export replaces its own
    d = tmp_path / "mine"
    d.mkdir()
    (d / "Makefile").write_text("mine\n")
    assert cli.main(["export-controller", str(d), "--controller", "pid"]) == 2
    assert "Makefile" in capsys.readouterr().err and (d / "Makefile").read_text() == "mine\n"
    assert cli.main(["export-controller", str(d), "--controller", "pid", "--force"]) == 0
    assert cli.main(["export-controller", str(d), "--controller", "pid"]) == 0
    m = json.loads((d / "arvcas-export.json").read_text())
    assert sorted(m["files"]) == sorted(f for f in files("arvcas_haidou1_pid_") if f != "arvcas-export.json")
    assert m["written_by"].endswith("export-controller")


def test_front_of_another_system_gives_its_controller(tmp_path, capsys):
    """The BlueROV2 front's knee: the export is sized by the front's system (8 thrusters)."""
    from pathlib import Path

    front = Path(__file__).resolve().parents[1] / "results/bluerov2/agsta/front.h5"
    out = tmp_path / "b2"
    assert cli.main(["export-controller", str(out), "--front", str(front), "--member", "knee",
                     "--allow-model-change"]) == 0
    h = (out / "arvcas_bluerov2_heavy_alpha5_agsta.h").read_text()
    assert "#define ARVCAS_BLUEROV2_HEAVY_ALPHA5_AGSTA_N_U 8" in h and "u[7]  T8" in h
    assert "#define ARVCAS_BLUEROV2_HEAVY_ALPHA5_AGSTA_USES_TAU_ARM 1" in h


def test_close_loop_refuses_a_current_and_the_thrust_quadrature():
    """The exported plant cannot carry a current, and close_loop's RK4 is not the thrust quadrature: one line
    each, before any work."""
    from types import SimpleNamespace

    from arvcas.export.controller import ExportError

    blue = load_system("bluerov2_heavy_alpha5")
    cfg = scenario.load_scenario(blue.params.default("scenario"))
    with pytest.raises(ExportError, match=r"^export-controller: close_loop .* sets time.thrust_quadrature \(5\), .* without it$"):
        close_loop(None, SimpleNamespace(cfg=cfg, params=blue.params))
    with pytest.raises(ExportError, match=r"^export-controller: close_loop .* a current acts inside .*\[current\]$"):
        close_loop(None, SimpleNamespace(cfg=replace(cfg, time_thrust_quadrature=None), params=blue.params))


def teardown_module(module):
    for (name, law), w in sorted(MEASURED.items()):
        print(f"\n{name}/{law}: " + ", ".join(f"{k} {v:.2g}" for k, v in w.items()), end="")
