"""The generated files' templates (arvcas/build/templates/*.j2, :mod:`arvcas.build.templating`).

Every template is rendered by one of the three exports (export-c of Haidou-1; export-controller of
Haidou-1's proposed law with the full state measured and of the BlueROV2 Heavy's PID, with its T200
command maps, from an IMU and a depth sensor; an FMU with its compiler stubbed), and checked against
Jinja2's own parse of its source: every name a template uses is given (in the branches that this
system did not take as well), every value given is used by a template it is given to, nothing of
the template syntax reaches the output, and a missing or unwritable value raises before anything is
written. That the output is byte-identical to the f-strings the templates replaced was checked once
by exporting every shipped (system, law) pair before and after (the change's commit message); that
the rendered C compiles and runs: tests/test_export.py, tests/test_export_controller.py, tests/test_fmu.py.
"""

from __future__ import annotations

import ast
import math
from dataclasses import replace
from pathlib import Path

import jinja2
import jinja2.meta
import pytest

from arvcas.build import export as ex
from arvcas.build import fmu as fmu_mod
from arvcas.build import templating
from arvcas.export import controller as ctl_mod
from arvcas.sim import scenario
from arvcas.system import load_system

# jinja2's floor, and the exported controller's casadi.extract_parametric (CI's floor job, docs/testing.md)
pytestmark = pytest.mark.floor

ROOT = Path(str(templating._environment().loader.searchpath[0]))
TEMPLATES = sorted(p.relative_to(ROOT).as_posix() for p in ROOT.rglob("*.j2"))


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """[(template, values, text)] of every render of the three exports."""
    calls = []
    real = templating.render

    def spy(template, values, error=templating.TemplateError):
        text = real(template, values, error)
        calls.append((template, values, text))
        return text

    tmp = tmp_path_factory.mktemp("templates")
    blue = load_system("bluerov2_heavy_alpha5")
    imu_depth = replace(scenario.load_scenario(blue.params.default("scenario")), sensors_imu_period=0.1,
                        sensors_depth_period=0.2)
    with pytest.MonkeyPatch.context() as mp:
        for mod in (ex, fmu_mod, ctl_mod):
            mp.setattr(mod, "render", spy)
        mp.setattr(fmu_mod, "_compile", lambda src, out: out.write_bytes(b""))  # tests/test_fmu.py compiles
        ex.export_c(tmp / "c")
        ctl_mod.export_controller(tmp / "h", "proposed")
        ctl_mod.export_controller(tmp / "b", "pid", params=blue, scenario=imu_depth)
        fmu_mod.export_fmu(tmp / "x.fmu")
    return calls


def _names(template: str) -> set[str]:
    env = templating._environment()
    return jinja2.meta.find_undeclared_variables(env.parse(env.loader.get_source(env, template)[0]))


def test_every_template_is_rendered(rendered):
    assert {t for t, _, _ in rendered} == set(TEMPLATES)


def test_every_name_a_template_uses_is_given(rendered):
    for template, values, _ in rendered:
        missing = _names(template) - set(values)
        assert not missing, f"{template}: {sorted(missing)} not given"


def test_every_value_given_is_used(rendered):
    used: dict[int, set[str]] = {}
    given: dict[int, tuple[str, set[str]]] = {}
    for template, values, _ in rendered:
        used.setdefault(id(values), set()).update(_names(template))
        given[id(values)] = (template, set(values))
    for key, (template, names) in given.items():
        assert names <= used[key], f"{template}: {sorted(names - used[key])} given but used by no template"


def test_no_template_syntax_reaches_the_output(rendered):
    for template, _, text in rendered:
        for mark in ("{{ ", " }}", "{%", "%}", "{#", "#}"):  # the templates' tags (C's {{1, 2}} is not one)
            assert mark not in text, f"{template}: {mark!r} in the output"
        assert text.endswith("\n") and not text.endswith("\n\n\n"), template
        if template.endswith(".py.j2"):
            ast.parse(text)  # the binding and the example are Python


def test_a_missing_value_raises():
    with pytest.raises(jinja2.UndefinedError, match="'lib' is undefined"):
        templating.render("export/consumer.CMakeLists.txt.j2", {"cflags": ["-O2"]})
    text = templating.render("export/consumer.CMakeLists.txt.j2", {"cflags": ["-O2"], "lib": "x"})
    assert "find_package(x CONFIG REQUIRED)" in text and "PRIVATE -O2)" in text


def test_an_unwritable_value_raises_the_callers_error_in_one_line(rendered):
    template, values, _ = next(c for c in rendered if c[0] == "controller/example.c.j2")
    bad = dict(values, example_y=[0.0, math.nan])
    with pytest.raises(ex.ExportError) as ei:
        templating.render(template, bad, ex.ExportError)
    assert "\n" not in str(ei.value) and "non-finite value nan" in str(ei.value)


def test_literals_read_back_as_the_same_double():
    for v in (0.1, 1.0, -2.5e-300, 1e22, 5e-324, math.pi, 123456789.123456789):
        s = templating.c_double(v)
        assert float(s) == v and ("." in s or "e" in s)
    assert templating.ident("arm.joint1.q-min") == "ARM_JOINT1_Q_MIN"
