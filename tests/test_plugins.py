"""Controllers from outside the package through the command line: an installed distribution's entry
point, a ``--plugin`` file and a study file's ``[study] plugins``; each is simulated, tuned, replayed from
its front and compared; a plugin that fails to import is one line and breaks no other command.

The distribution is written by hand into a temporary directory put on ``sys.path`` (its module and a
``.dist-info`` with ``entry_points.txt``: what ``pip install`` leaves, found by ``importlib.metadata``).
The entry point's module and the ``--plugin`` file are the same source under the same module name
(``toy_plugin``), so they share one pair of compiled libraries (the compile cache is keyed by the law's
identity and its source's digest): two compiles for the whole module.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from arvcas import cli
from arvcas.controllers import base
from arvcas.util import plugins
from arvcas.io.results import read_result
from arvcas.model.spatial import J
from arvcas.tuning import checkpoint as ck
from arvcas.tuning.front import read_front
from studytext import tiny_study

ROOT = Path(__file__).resolve().parents[1]

LAW = '''\
"""A law from outside arvcas: a linear sliding surface with a fixed gain (a test's plugin)."""
import casadi as ca

import arvcas
from arvcas.model.spatial import J
from arvcas.sim.signals import DOFS, RATE_UNITS, Signal


class ToySMC(arvcas.Controller):
    name = "toy_smc"
    description = "s = e_dot + lam e, tau_eta = -Mhat k1 s"
    gains = (arvcas.Gain("k1", "1/s", "gain on s"), arvcas.Gain("lam", "1/s", "slope of the surface"))
    defaults = [1.6, 0.375] * 6
    defaults_block = "toy_smc"
    signals = (Signal("s", 6, RATE_UNITS, "{n}", DOFS, "sliding variable", lambda c: c.out["s"]),
               Signal("k1", 6, "1/s", "", DOFS, "the gain k1", lambda c: c.out["k1"]))

    def initial(self, ctx, G):
        return {}

    def step(self, ctx, G, x):
        s = ctx.e_dot + G["lam"] * ctx.e
        ctx.out["s"], ctx.out["k1"] = s, G["k1"]
        return ca.mtimes(J(ctx.eta_hat).T, ctx.Mhat * (-G["k1"] * s)), {}
'''

DIST = "toy_arvcas_plugin-0.1.dist-info"
ENTRY_POINTS = "[arvcas.controllers]\ntoy_smc = toy_plugin:ToySMC\nbroken_law = toy_broken:Law\n"
BROKEN = 'import arvcas\nraise RuntimeError("the lab licence server is down")\n'


@pytest.fixture
def site(tmp_path, monkeypatch):
    """The installed distribution: toy_plugin.py, toy_broken.py and their .dist-info, on sys.path."""
    d = tmp_path / "site"
    (d / DIST).mkdir(parents=True)
    (d / "toy_plugin.py").write_text(LAW)
    (d / "toy_broken.py").write_text(BROKEN)
    (d / DIST / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-arvcas-plugin\nVersion: 0.1\n")
    (d / DIST / "entry_points.txt").write_text(ENTRY_POINTS)
    monkeypatch.syspath_prepend(str(d))
    return d


def _run(capsys, *argv):
    rc = cli.main([str(a) for a in argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


def _study(path: Path, seed: int, plugins_line: str = "") -> Path:
    text = tiny_study(controller="toy_smc", seed=seed, population=6, generations=2, include_table2=True, name="toy")
    path.write_text(text.replace(f"seed = {seed}\n", f"seed = {seed}\n{plugins_line}", 1))
    return path


def _law_holds(r) -> None:
    """The plugin's law ran: tau_cmd = J^T Mhat (-k1 s) at the traced samples, k1 the default gain."""
    from arvcas.model import vehicle
    from arvcas.system.params import load, view

    mhat = np.diag(np.asarray(ca.DM(vehicle.M(view(ca.DM(load().vector()))))))
    np.testing.assert_array_equal(r.k1[5], np.full(6, 1.6))
    for k in (1, 300, len(r.t) - 1):
        Jk = np.asarray(ca.DM(J(ca.DM(r.eta_hat[k]))))
        np.testing.assert_allclose(r.tau_cmd[k], Jk.T @ (mhat * (-1.6 * r.s[k])), rtol=1e-12, atol=1e-9)


def _replays(capsys, tmp_path, front: Path, *extra) -> None:
    """simulate --from-front reproduces member 0's stored per-DOF CHAT and RMSE bit for bit."""
    out = tmp_path / f"replay_{front.parent.name}.h5"
    rc, text, err = _run(capsys, "simulate", "--from-front", front, "--index", "0", "--out", out, *extra)
    assert rc == 0, err
    fr = read_front(front)
    r = read_result(out)
    np.testing.assert_array_equal(r.chat, fr.chat[0, 0])
    np.testing.assert_array_equal(r.rmse, fr.rmse[0, 0])


def test_entry_point_plugin_through_every_command(site, fresh, tmp_path, capsys):
    # a built-in controller never looks at the entry points (a broken plugin cannot break it)
    base.get("pid")
    assert plugins._EP_DONE == {}
    # simulate: the name is found among the entry points, lazily
    rc, text, err = _run(capsys, "simulate", "--controller", "toy_smc", "--seed", "1", "--out", tmp_path / "r.h5")
    assert rc == 0, err
    assert text.startswith("toy_smc: seed 1, 100 s, ok")
    src = base.origin("toy_smc")
    assert src.kind == "entry point" and src.distribution == "toy-arvcas-plugin 0.1"
    assert src.entry_point == "arvcas.controllers: toy_smc = toy_plugin:ToySMC"
    assert "toy_broken" not in sys.modules  # only the entry point of that name was loaded
    r = read_result(tmp_path / "r.h5")
    _law_holds(r)
    assert r.meta["controller_source"]["kind"] == "entry point"
    # tune (the study names the controller only), twice, and compare the two fronts
    for seed, out in ((3, "out"), (4, "out2")):
        rc, text, err = _run(capsys, "tune", _study(tmp_path / f"s{seed}.toml", seed), "--out", tmp_path / out)
        assert rc == 0, err
    c = ck.read_checkpoint(tmp_path / "out" / "front.h5")
    assert c.plugin["kind"] == "entry point" and c.plugin["distribution"] == "toy-arvcas-plugin 0.1"
    assert c.plugin["digest"] == plugins.digest([site / "toy_plugin.py"]) and c.plugin["class"] == "toy_plugin.ToySMC"
    _replays(capsys, tmp_path, tmp_path / "out" / "front.h5")
    rc, text, err = _run(capsys, "compare", tmp_path / "out", tmp_path / "out2")
    assert rc == 0 and "toy_smc (out)" in text, err
    # a fresh process finds the entry point by itself (the command that said "unknown controller")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(site)]))
    p = subprocess.run([sys.executable, "-m", "arvcas.cli", "simulate", "--from-front", str(tmp_path / "out"),
                        "--index", "0"], capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 0 and p.stdout.startswith("toy_smc: seed 0, 100 s, ok"), p.stderr
    # the broken entry point: one line naming it, its distribution and the error, for the command that asks
    rc, text, err = _run(capsys, "simulate", "--controller", "broken_law")
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert ("entry point 'arvcas.controllers: broken_law = toy_broken:Law' of distribution toy-arvcas-plugin 0.1: "
            "RuntimeError: the lab licence server is down (toy_broken.py, line 2)") in err
    # the listing shows what loads and warns once about what does not
    rc, text, err = _run(capsys, "controllers")
    assert rc == 0 and "toy_smc" in text and "entry point" in text
    assert err.count("\n") == 1 and err.startswith("warning: entry point 'arvcas.controllers: broken_law")


def test_plugin_file_and_study_plugins(fresh, tmp_path, capsys):
    d = tmp_path / "lab"
    d.mkdir()
    law = d / "toy_plugin.py"
    law.write_text(LAW)
    # simulate --plugin FILE
    rc, text, err = _run(capsys, "simulate", "--plugin", law, "--controller", "toy_smc", "--out", tmp_path / "r.h5")
    assert rc == 0, err
    assert base.origin("toy_smc").kind == "file" and sys.modules["toy_plugin"].__file__ == str(law)
    _law_holds(read_result(tmp_path / "r.h5"))
    # tune from a study file naming the plugin relative to itself
    study = _study(d / "study.toml", 3, 'plugins = ["toy_plugin.py"]\n')
    rc, text, err = _run(capsys, "tune", study, "--out", tmp_path / "out")
    assert rc == 0, err
    front = tmp_path / "out" / "front.h5"
    c = ck.read_checkpoint(front)
    assert c.plugin["kind"] == "file" and c.plugin["spec"] == str(law)
    # a new process without the plugin: one line saying which plugin to load
    fresh()
    rc, text, err = _run(capsys, "simulate", "--from-front", front, "--index", "0")
    assert rc == 2 and err.count("\n") == 1, err
    assert f"controller 'toy_smc' is not registered; it came from plugin file {law}" in err
    assert f"load it with --plugin {law}" in err
    _replays(capsys, tmp_path, front, "--plugin", law)
    rc, text, err = _run(capsys, "montecarlo", "--from-front", front, "--index", "knee", "--runs", "2",
                         "--out", tmp_path / "mc.h5", "--plugin", law)
    assert rc == 0, err
    rc, text, err = _run(capsys, "sweep", "--h", "0.1", "--controllers", "toy_smc", "--out", tmp_path / "sw",
                         "--plugin", law)  # its k1 and s signals are what the sweep measures
    assert rc == 0 and "toy_smc" in text, err
    fresh()  # the files say which plugin re-runs them
    for argv in (("montecarlo", "--check", tmp_path / "mc.h5"), ("sweep", "--check", tmp_path / "sw" / "sweep.h5")):
        rc, text, err = _run(capsys, *argv)
        assert rc == 2 and err.count("\n") == 1 and f"load it with --plugin {law}" in err, err
    rc, text, err = _run(capsys, "montecarlo", "--check", tmp_path / "mc.h5", "--plugin", law)
    assert rc == 0 and "reproduced bit for bit" in text, err
    # compare a front of the file plugin with the one of the study's second seed (loaded by the study)
    rc, text, err = _run(capsys, "tune", _study(d / "s4.toml", 4, 'plugins = ["toy_plugin.py"]\n'), "--out",
                         tmp_path / "out2")
    assert rc == 0, err
    rc, text, err = _run(capsys, "compare", tmp_path / "out", tmp_path / "out2")
    assert rc == 0, err
    # the plugin's source changed: refused like a model change, before any compile
    law.write_text(LAW + "# edited\n")
    rc, text, err = _run(capsys, "simulate", "--from-front", front, "--index", "0", "--plugin", law)
    assert rc == 2 and "the source of controller 'toy_smc' changed" in err and "--allow-model-change" in err, err
    rc, text, err = _run(capsys, "tune", study, "--out", tmp_path / "out", "--resume")
    assert rc == 2 and "the source of controller 'toy_smc' changed" in err, err
    rc, text, err = _run(capsys, "compare", tmp_path / "out", tmp_path / "out2")
    assert rc == 0, err  # both fronts were computed from the same source


def test_broken_plugin_file_is_one_line(tmp_path, fresh, capsys):
    bad = tmp_path / "bad_law.py"
    bad.write_text("import arvcas\n\nclass Law(arvcas.Controller):\n    name = 'bad'\n    def step(self, ctx, G, x)\n")
    rc, text, err = _run(capsys, "simulate", "--plugin", bad, "--controller", "pid")
    assert rc == 2 and err == f"arvcas: error: --plugin {bad}: SyntaxError: expected ':' (bad_law.py, line 5)\n"
    bad.write_text("import numpy\nx = numpy.zeros(2)[5]\n")
    rc, text, err = _run(capsys, "sweep", "--plugin", bad, "--h", "0.1", "--out", tmp_path / "o")
    assert rc == 2 and err.startswith(f"arvcas: error: --plugin {bad}: IndexError: index 5 is out of bounds")
    assert err.endswith("(bad_law.py, line 2)\n") and err.count("\n") == 1
    for spec, msg in ((tmp_path / "none.py", "plugin file not found"), ("no_such_module_xyz", "ModuleNotFoundError"),
                      ("not a module", "neither a Python file")):
        rc, text, err = _run(capsys, "montecarlo", "--plugin", spec, "--controller", "pid", "--runs", "1",
                             "--out", tmp_path / "mc.h5")
        assert rc == 2 and msg in err and err.count("\n") == 1, err
    # a study's plugin: the study file and the key
    study = tmp_path / "s.toml"
    study.write_text(tiny_study(controller="pid").replace("seed = 3\n", 'seed = 3\nplugins = "bad_law.py"\n'))
    rc, text, err = _run(capsys, "tune", study, "--out", tmp_path / "out")
    assert rc == 2 and err.startswith(f"arvcas: error: {study}: study.plugins: {bad}: IndexError"), err
    assert not (tmp_path / "out").exists()


def test_what_a_plugin_module_registers(tmp_path, fresh):
    """adopt: classes with a name defined in the module, instances it holds, a law it registered itself;
    not imported classes nor nameless bases; a clash is one line naming the plugin."""
    f = tmp_path / "two_laws.py"
    f.write_text(LAW.replace("toy_smc", "toy_a") + "\n\nclass _Base(ToySMC):\n    name = ''\n\n"
                 "class B(ToySMC):\n    name = 'toy_b'\n\narvcas.register_controller(B())\n\n"
                 "from arvcas.controllers.pid import PID\n")
    p = plugins.load(f)
    assert p.kind == "file" and p.module == "two_laws"
    assert {n for n in base.names() if n.startswith("toy_")} == {"toy_a", "toy_b"}
    assert base.origin("toy_a") == p and base.origin("toy_b") == p  # the self-registered one too
    assert plugins.load(str(f)) is p  # once per process
    clash = tmp_path / "clash.py"
    clash.write_text(LAW.replace("toy_smc", "toy_a"))
    with pytest.raises(plugins.PluginError, match=rf"^--plugin {re.escape(str(clash))}: register: a controller named "
                                                  rf"'toy_a' exists"):
        plugins.load(clash)
    # a file whose name an importable module holds gets a private module name
    j = tmp_path / "json.py"
    j.write_text(LAW.replace("toy_smc", "toy_j"))
    assert plugins.load(j).module.startswith("arvcas_plugin_json_")
    import json

    assert sys.modules["json"] is json
    with pytest.raises(ValueError, match="unknown group"):
        plugins.add_registry("arvcas.scenarios", lambda obj: [])


def test_a_later_registry_gets_the_same_discovery(tmp_path, fresh, monkeypatch):
    """The group arvcas.objectives is reserved: a registry declared later (objectives as objects) is handed
    what plugins loaded before gave, and its entry points load like the controllers'."""
    monkeypatch.setattr(plugins, "_ADOPT", dict(plugins._ADOPT))
    f = tmp_path / "lab_objectives.py"
    f.write_text("class Energy:\n    name = 'energy'\n")
    plugins.load(f)
    d = tmp_path / "site"
    (d / "lab_obj-1.0.dist-info").mkdir(parents=True)
    (d / "lab_obj-1.0.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: lab-obj\nVersion: 1.0\n")
    (d / "lab_obj-1.0.dist-info" / "entry_points.txt").write_text("[arvcas.objectives]\npeak = lab_objectives:Energy\n")
    monkeypatch.syspath_prepend(str(d))
    got = []

    def adopt(obj):
        got.append(obj)
        return [getattr(obj, "name", "")]

    plugins.add_registry("arvcas.objectives", adopt)
    assert [getattr(o, "__name__", None) for o in got] == ["lab_objectives"]  # the module loaded before
    assert plugins.find("arvcas.objectives", "peak") == ["energy"]
    assert got[-1] is sys.modules["lab_objectives"].Energy and plugins.failures("arvcas.objectives") == []


def test_source_digest_keys_the_compiled_run(tmp_path, fresh, monkeypatch):
    """A plugin package's every file counts (a helper module too); its digest is in the run's cache key."""
    import arvcas

    pkg = tmp_path / "toy_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("from toy_pkg.law import ToySMC\n")
    (pkg / "helpers.py").write_text("LAM = 0.375\n")
    (pkg / "law.py").write_text(LAW.replace("toy_smc", "toy_pkg_law"))
    monkeypatch.syspath_prepend(str(tmp_path))
    plugins.load("toy_pkg")
    law = base.get("toy_pkg_law")
    assert law.own_source_files() == sorted(str(pkg / n) for n in ("__init__.py", "helpers.py", "law.py"))
    run = arvcas.Run("toy_pkg_law").compile()
    key = run.description(False)
    assert f"own_source={law.source_digest()}" in key
    (pkg / "helpers.py").write_text("LAM = 0.4\n")
    assert run.description(False) != key
    assert base.provenance("toy_pkg_law")["kind"] == "module"
    # the package's own laws have no source of their own: their cache key is unchanged
    assert base.get("pid").own_source_files() == [] and base.provenance("pid") == {}


def test_dask_worker_loads_the_plugin(fresh, tmp_path):
    """A Dask chunk in a process without the plugin loads it from the task (the libraries are cached)."""
    from arvcas.sim.scenario import load_scenario
    from arvcas.system.params import load
    from arvcas.tuning.engines import EvalTask, _chunk

    law = tmp_path / "toy_plugin.py"
    law.write_text(LAW)
    plugins.load(law)
    g = base.get("toy_smc")
    from arvcas.controllers import gains as gains_mod

    G = gains_mod.default_gains(g)[None, :]
    task = EvalTask("toy_smc", ((0, np.ones(4), np.zeros(6)),), load_scenario(), load(), plugins=(str(law),))
    want = _chunk(task, G, 1)
    fresh()
    assert "toy_smc" not in base.names()
    got = _chunk(task, G, 1)
    np.testing.assert_array_equal(got[0], want[0])
    assert got[4] == want[4] and base.origin("toy_smc").kind == "file"


def test_every_command_that_takes_a_controller_takes_plugins():
    """From the one table: a command with a controller option or a front to replay has --plugin (and the
    listing of the controllers)."""
    ap = cli._parser()
    for c in cli.TABLE:
        sub = ap._subparsers._group_actions[0].choices[c.name.split()[0]]
        if " " in c.name:
            sub = sub._subparsers._group_actions[0].choices[c.name.split()[1]]
        opts = {o for a in sub._actions for o in a.option_strings}
        takes = bool(opts & {"--controller", "--controllers", "--from-front", "--front"}) or \
            any(kind == "front" for _, kind, *_ in c.inputs) and c.name not in ("front export", "front plot") or \
            c.name == "controllers"
        assert c.plugins == takes and ("--plugin" in opts) == takes, c.name
