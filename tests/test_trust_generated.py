"""Generated text: a user's strings (a system file's description, path, sources, names) reach C headers,
C string literals, build files and the FMU's modelDescription.xml only through arvcas.build.text, so
no string can end a comment, add code, or make the XML malformed. Property tests throw arbitrary and
hostile strings at every such field and preprocess (C) or schema-validate (XML) the result."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import casadi as ca
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from arvcas import cli
from arvcas.build import export, text
from arvcas.system import load_system

CC = shutil.which("cc")
pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler")

# pieces a hostile string is made of: comment ends and starts, a line splice, trigraphs, quotes, XML
# markup, NUL and other control characters, bidi overrides, line separators, non-ASCII
HOSTILE = ["*", "/", "\\", "\n", "\r", "\r\n", "?", "??/", "*/", "/*", "//", '"', "'", "<", ">", "&", "]]>",
           "--", "\x00", "\x01", "\x1b", "\x7f", "\u202e", "\u2028", "\ufeff", "\udc80", "\uffff", "é", "µ",
           "#define X", "a", " ", "}", "__attribute__((constructor))"]
HOSTILE_TEXT = st.one_of(st.text(max_size=40), st.lists(st.sampled_from(HOSTILE), max_size=12).map("".join))
PROPERTY = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

# the probe's attack: '*', a backslash-newline, '/' closes the comment; then a constructor
ATTACK = ('x *\\\n/ __attribute__((constructor)) static void arvcas_pwned(void) '
          '{ __builtin_trap(); } /* ')


@pytest.fixture(scope="module")
def blue():
    return load_system("bluerov2_heavy_alpha5").params


@pytest.fixture(scope="module")
def header_parts(blue):
    """What export-c's header needs besides the system's text: the functions and CasADi's C."""
    from arvcas.build.dynamics import jacobian_functions
    from arvcas.model.uvms import PUBLIC_FUNCTIONS, ModelOptions, plant_functions

    opts = ModelOptions()
    plant = plant_functions(opts, blue.layout)
    fns = {n: plant[n] for n in PUBLIC_FUNCTIONS}
    fns.update(jacobian_functions(plant))
    prefix = export.default_prefix(blue)
    cg = ca.CodeGenerator(prefix.rstrip("_"), {"with_header": False, "casadi_real": "double",
                                               "casadi_int": "long long int"})
    for short, f in fns.items():
        sym = f.sx_in()
        cg.add(ca.Function(prefix + short, sym, f.call(sym), f.name_in(), f.name_out()))
    return fns, cg.dump(), prefix, opts


def _tokens(path: Path, lang: str = "c") -> str:
    """The preprocessed tokens of ``path`` (comments gone), trigraphs on, comment warnings as errors."""
    r = subprocess.run([CC, "-E", "-P", "-trigraphs", "-Werror", "-Wcomment", "-Wtrigraphs", "-x", lang, str(path)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    return " ".join(r.stdout.split())


def _headers(parts, P, d: Path) -> Path:
    fns, c_text, prefix, opts = parts
    h = d / "both.h"
    v = export._values(fns, c_text, prefix, opts, P, export.example_inputs(P))
    h.write_text(export._render("export/plant.h.j2", v) + export.params_header(P, opts, prefix), encoding="utf-8")
    return h


def _with_text(P, s: str):
    return dataclasses.replace(P, description=s, path=s, _sources=tuple(s for _ in P._sources))


def test_c_comment_and_string_by_construction():
    assert text.c_comment("a */ b /* c ??/ d \\") == "a * / b / * c ? ?/ d <U+005C>"
    assert text.c_comment("x\ny\u202e") == "x<U+000A>y<U+202E>"
    assert text.c_comment_lines("one\r\ntwo */") == ["one", "two * /"]
    assert text.c_string('say "hi"\\\n??/ é\x00') == r'"say \"hi\"\\\n\?\?/ \303\251<U+0000>"'
    assert text.xml_attr('a"<&\n\x01') == "'a\"&lt;&amp;&#10;&lt;U+0001&gt;'"
    for bad in ("a b", "$(shell rm -rf /)", "x\ny", "", "${X}", "a;b", "é"):
        with pytest.raises(ValueError, match="not a plain word"):
            text.build_word(bad, "flag")
    for bad in ("a b_", "x$(shell id)_", "x\n_"):  # the build files take only plain words
        with pytest.raises(export.ExportError, match="not a plain word"):  # Makefile and both CMake files
            export.build_files(bad)


@PROPERTY
@given(s=HOSTILE_TEXT)
def test_header_text_is_inert(s, blue, header_parts, tmp_path_factory):
    """Any description/path/source: the headers preprocess (C, trigraphs on) to the same tokens as with a
    plain one, with no comment warning."""
    d = tmp_path_factory.mktemp("h")
    if "plain" not in _PLAIN:
        _PLAIN["plain"] = _tokens(_headers(header_parts, _with_text(blue, "plain"), d))
    assert _tokens(_headers(header_parts, _with_text(blue, s), d)) == _PLAIN["plain"]


_PLAIN: dict[str, str] = {}  # the headers' tokens with a plain text, computed once


@PROPERTY
@given(s=HOSTILE_TEXT)
def test_c_string_is_one_literal(s, tmp_path_factory):
    """Any string as a C string literal: compiles, and is exactly the UTF-8 bytes of its visible text."""
    d = tmp_path_factory.mktemp("s")
    lit = text.c_string(s)
    want = text.visible(s, newlines=True).encode("utf-8")
    src = d / "s.c"
    src.write_text(f"static const char s[] = {lit};\n_Static_assert(sizeof s == {len(want) + 1}, \"size\");\n"
                   f"const char *get(void) {{ return s; }}\n", encoding="utf-8")
    r = subprocess.run([CC, "-c", "-trigraphs", "-Werror", "-Wall", "-o", str(d / "s.o"), str(src)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]


@pytest.fixture(scope="module")
def fmu_parts(blue):
    from arvcas.build import fmu

    V = fmu.variables(blue)
    return fmu, V


@PROPERTY
@given(s=HOSTILE_TEXT)
def test_model_description_is_valid_xml(s, blue, fmu_parts, tmp_path_factory):
    """Any description and source: modelDescription.xml validates against the FMI 2.0 schema (FMPy) and
    carries the visible text."""
    from fmpy.model_description import read_model_description

    fmu, V = fmu_parts
    P = _with_text(blue, s)
    V2 = [dict(v, description=s) if v["causality"] == "parameter" else v for v in V]
    xml = fmu._model_description(V2, [[1]] * 12, "{00000000-0000-0000-0000-000000000000}", "wrench", P)
    f = tmp_path_factory.mktemp("x") / "modelDescription.xml"
    f.write_text(xml, encoding="utf-8")
    read_model_description(str(f), validate=True)
    root = ET.fromstring(xml.encode("utf-8"))
    assert text.visible(s, newlines=True) in root.get("description")
    names = [v.get("description") for v in root.iter("ScalarVariable") if v.get("causality") == "parameter"]
    assert names[-1] == text.visible(s, newlines=True)


def _hostile_system(tmp_path: Path) -> Path:
    """The shipped BlueROV2 with the attack as description, in a folder whose name puts */ in the path."""
    from arvcas.system import shipped

    src = shipped()["bluerov2_heavy_alpha5"]
    d = tmp_path / "x*"
    d.mkdir()
    for f in src.parent.glob("bluerov2_heavy_alpha5.*toml"):
        shutil.copy(f, d / f.name)
    body = (d / src.name).read_text(encoding="utf-8")
    old = next(ln for ln in body.splitlines() if ln.startswith("description = "))
    toml_attack = ATTACK.replace("\\", "\\\\").replace("\n", "\\n")
    (d / src.name).write_text(body.replace(old, f'description = "{toml_attack}"'), encoding="utf-8")
    return d / src.name


def test_export_c_with_the_probes_attack_compiles_to_nothing_but_main(tmp_path, capsys):
    """The probe's attack (description and path) through `arvcas export-c`: a C and a C++ program
    including both headers define no symbol but main."""
    system = _hostile_system(tmp_path)
    assert "*/" in str(system)
    out = tmp_path / "out"
    assert cli.main(["export-c", "--system", str(system), str(out)]) == 0, capsys.readouterr().err
    lib = export.default_prefix(load_system(system)).rstrip("_")
    h = (out / f"{lib}.h").read_text(encoding="utf-8")
    assert "arvcas_pwned" in h and "<U+005C>" in h  # the text is there, inert
    for lang, tool in (("c", CC), ("c++", shutil.which("c++"))):
        if tool is None:
            pytest.skip(f"no {lang} compiler is installed (the program was built as C only)")
        src = out / f"probe.{'c' if lang == 'c' else 'cpp'}"
        src.write_text(f'#include "{lib}.h"\n#include "{lib}_params.h"\nint main(void) {{ return 0; }}\n')
        obj = out / f"probe-{lang}.o"
        r = subprocess.run([tool, "-c", "-trigraphs", "-Wall", "-Werror", "-o", str(obj), str(src)],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr[-2000:]
        nm = subprocess.run(["nm", "--defined-only", str(obj)], capture_output=True, text=True, timeout=60)
        defined = [ln.split()[-1] for ln in nm.stdout.splitlines() if ln.split()[1] in "TtDdBb"]
        assert defined == ["main"], defined


@PROPERTY
@given(name=HOSTILE_TEXT, thruster=HOSTILE_TEXT, description=HOSTILE_TEXT)
@example(name="rov\n", thruster="T1", description=ATTACK)
@example(name="rov", thruster="T1\n", description="")
@example(name="rov", thruster="class", description="")
@example(name="rov", thruster="T_9", description="\u202e")
def test_system_file_strings_load_or_refuse_in_one_line(name, thruster, description, tmp_path_factory):
    """Any system name, thruster name and description in a system file: it loads (and every name is a plain
    identifier) or is refused with one line naming the file."""
    import json

    from arvcas.system.params import ParamsError, load
    from arvcas.system import shipped

    body = shipped()["bluerov2_heavy_alpha5"].read_text(encoding="utf-8")
    q = lambda s: json.dumps(s, ensure_ascii=True)  # noqa: E731 - a TOML basic string (or an invalid escape)
    body = body.replace('name = "bluerov2_heavy_alpha5"', f"name = {q(name)}", 1)
    body = body.replace('name = "T1"', f"name = {q(thruster)}", 1)
    body = body.replace('description = "BlueROV2 Heavy', f'description = {q(description)}\n_d = "', 1)
    body = body.replace('\n_d = "', "\n# ", 1)
    d = tmp_path_factory.mktemp("sys")
    (d / "s.toml").write_text(body.split("[defaults]")[0], encoding="utf-8")
    try:
        P = load(d / "s.toml")
    except ParamsError as e:
        msg = str(e)
        assert msg.startswith(str(d / "s.toml")) and "\n" not in msg, msg
        return
    assert P.structure.name == name and P.structure.thrusters[0] == thruster
    assert name.isidentifier() and name.isascii() and thruster.isidentifier() and thruster.isascii()
