"""One vocabulary: ``system=`` for what is a system, the old ``params=`` kept one release with a
DeprecationWarning naming the new keyword (a user's code does not break silently), and the default system
named once (:data:`arvcas.system.DEFAULT`). Nothing here compiles: every call is refused or described
before any build."""

from __future__ import annotations

import argparse
from pathlib import Path
import warnings

import pytest

import arvcas
from arvcas.build import export, fmu
from arvcas.io.cliargs import add_system_arg
from arvcas.sim import closedloop
from arvcas.system import DEFAULT, UNSET, load_system, renamed_system
from arvcas.system.params import default_path


def test_the_default_system_is_named_once():
    assert DEFAULT == arvcas.system.loader.DEFAULT == arvcas.system.params.DEFAULT
    assert default_path().name == f"{DEFAULT}.toml"
    assert load_system().name == load_system(None).name == DEFAULT
    assert export.DEFAULT_PREFIX == export.default_prefix() == f"arvcas_{DEFAULT}_"
    p = argparse.ArgumentParser()
    add_system_arg(p)
    assert p.parse_args([]).system is None and str(p.parse_args(["--params", "x.toml"]).system) == "x.toml"
    assert f"the default system, {DEFAULT}" in p.format_help()


def test_run_takes_system_and_the_old_keyword_warns():
    s = load_system("bluerov2_heavy_alpha5")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        new = arvcas.Run("pid", system=s.params)
        assert arvcas.Run("pid", None, s.params) == new  # the third positional argument is the system
    with pytest.warns(DeprecationWarning, match=r"params= is now system="):
        old = arvcas.Run("pid", params=s.params)
    assert old == new and old.system is s.params
    with pytest.warns(DeprecationWarning, match=r"Run.params is now Run.system"):
        assert new.params is s.params
    with pytest.raises(TypeError, match="system= and params= .* both given"):
        arvcas.Run("pid", system=s.params, params=s.params)


def test_every_renamed_keyword_warns_and_still_works(tmp_path):
    s = load_system("bluerov2_heavy_alpha5")
    with pytest.warns(DeprecationWarning, match="layout: the keyword params= is now system="):
        assert fmu.layout(params=s.params) == fmu.layout(system=s.params) == fmu.layout(s.params)
    with pytest.warns(DeprecationWarning, match="variables: the keyword params="):
        assert [v["name"] for v in fmu.variables(params=s.params)] == [v["name"] for v in fmu.variables(s.params)]
    with pytest.warns(DeprecationWarning, match="simulate: the keyword params="), \
            pytest.raises(arvcas.sim.run.SimulationError, match="system: expected"):
        arvcas.simulate("pid", params={"env.rho": 1.0})
    with pytest.warns(DeprecationWarning, match="export_c: the keyword params="), \
            pytest.raises(export.ExportError, match="force"):
        export.export_c(tmp_path / "out", params=s.params, force="yes")


def test_the_helper():
    assert renamed_system("a", UNSET, "f") == "a" and renamed_system(None, UNSET, "f") is None
    with pytest.warns(DeprecationWarning):
        assert renamed_system(None, "b", "f") == "b"


def test_the_loop_states_layout_is_not_the_parameter_layout():
    assert closedloop.StateLayout is not arvcas.system.params.Layout
    with pytest.warns(DeprecationWarning, match="closedloop.Layout is now StateLayout"):
        assert closedloop.Layout is closedloop.StateLayout


# ---- controllers named by what they are (the paper's names stay the registered ones) -----------------

ALIASES = {"agsta_reso_decay": "proposed", "agsta_reso_updown": "traditional", "agsta_nominal": "agsta"}


def test_each_law_has_a_name_that_says_what_it_is_and_resolves_to_the_papers():
    from arvcas.controllers import base, gains
    from arvcas.export.controller import default_prefix

    assert {a: base.aliases()[a] for a in ALIASES} == ALIASES
    for alias, name in ALIASES.items():
        assert base.get(alias) is base.get(name) and base.canonical(alias) == name
        assert gains.check_controller(alias) == name
        assert (gains.default_gains(alias) == gains.default_gains(name)).all()
        assert default_prefix(None, alias) == default_prefix(None, name) == f"arvcas_{DEFAULT}_{name}_"
    assert base.canonical("pid") == "pid" and base.canonical("nope") == "nope"
    assert "agsta_reso_decay" not in base.names() and "agsta_reso_decay" in base.accepted()
    assert base.get("implicit").name == "implicit"  # a subclass of proposed does not inherit its alias


def test_an_alias_cannot_take_another_laws_name():
    from arvcas.controllers import base
    from arvcas.controllers.pid import PID

    class Clash(PID):
        name = "clash_pid"
        aliases = ("agsta_reso_decay",)

    with pytest.raises(base.ControllerError, match="alias 'agsta_reso_decay' already names controller 'proposed'"):
        base.register(Clash())
    assert "clash_pid" not in base.names()

    class Renamed(PID):
        name = "renamed_pid"
        aliases = ("also_pid",)

    try:
        base.register(Renamed())
        assert base.get("also_pid").name == "renamed_pid"
    finally:
        base.unregister("renamed_pid")
    assert "also_pid" not in base.aliases()


def test_the_command_line_and_study_files_take_an_alias(tmp_path, capsys):
    from arvcas import cli
    from arvcas.tuning.study import loads_study

    assert cli.main(["controllers"]) == 0
    assert "agsta_reso_decay = proposed" in capsys.readouterr().out
    src = Path(__file__).resolve().parents[1] / "studies"
    text = (src / "quick.toml").read_text()
    assert 'controllers = "proposed"' in text
    study = loads_study(text.replace('controllers = "proposed"', 'controllers = "agsta_reso_decay"'), "alias", src)
    assert study.controllers == ("proposed",)
    with pytest.raises(ValueError, match="named twice"):
        loads_study(text.replace('controllers = "proposed"', 'controllers = ["proposed", "agsta_reso_decay"]'),
                    "alias", src)


def test_a_command_is_given_the_registered_name_of_an_alias():
    from arvcas import cli

    a = argparse.Namespace(controller="agsta_nominal", controllers=["agsta_reso_updown", "pid"])
    cli._canonical_controllers(a)
    assert (a.controller, a.controllers) == ("agsta", ["traditional", "pid"])
    b = argparse.Namespace(controller=None)
    cli._canonical_controllers(b)
    assert b.controller is None
