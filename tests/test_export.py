"""``arvcas export-c`` end to end and the ``arvcas`` command line.

export-c: build the exported library with make and with CMake (and a project using its installed
package config), run the C, C++ and Python ctypes examples and compare every output with CasADi's VM
to 1e-12 relative; symbols, header, flags, and the refusal to replace files arvcas did not write.
Every export test runs for both shipped systems (Haidou-1: 6 thrusters, 6 joints, 140 parameters;
the BlueROV2 Heavy + Alpha 5: 8 thrusters, 4 joints, 239 parameters).
Command line: one-line errors with exit code 2, ``cache``, ``demo``.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

import arvcas
from arvcas import cli
from arvcas.build import codegen
from arvcas.build.dynamics import NAMES, jacobian_functions
from arvcas.build.export import (DEFAULT_PREFIX, MANIFEST, ExportError, _check_reentrant, default_prefix,
                                 example_inputs, export_c, files)
from arvcas.model import uvms
from arvcas.system.params import load
from arvcas.system import SHIPPED, load_system

from make_helpers import make_cmd

RTOL = 1e-12


@pytest.fixture(scope="module", params=SHIPPED[:2])
def system(request):
    """Haidou-1 and the BlueROV2 Heavy in turn (the export fixtures below are per system). The third shipped
    system, hinsdale_bluerov2_alpha5, has the BlueROV2's structure (8-thruster list, 4-joint chain arm),
    trim off: exporting it would add CI time but no code path (tests/test_hinsdale.py checks it)."""
    return load_system(request.param)


@pytest.fixture(scope="module")
def prefix(system):
    return default_prefix(system)


@pytest.fixture(scope="module")
def plant(system):
    fns = dict(uvms.plant_functions(uvms.ModelOptions(), system.layout))
    fns.update(jacobian_functions(fns))
    return fns


@pytest.fixture(scope="module")
def exported(tmp_path_factory, system):
    out = tmp_path_factory.mktemp("export") / "plant_c"
    argv = ["export-c", str(out)] if system.name == "haidou1" else ["export-c", "--system", system.name, str(out)]
    assert cli.main(argv) == 0
    return out


def test_default_prefix_names_the_system():
    assert default_prefix() == default_prefix("haidou1") == DEFAULT_PREFIX == "arvcas_haidou1_"
    assert default_prefix("bluerov2_heavy_alpha5") == "arvcas_bluerov2_heavy_alpha5_"
    assert files() == files(DEFAULT_PREFIX) and files(default_prefix("bluerov2_heavy_alpha5"))[0] == \
        "arvcas_bluerov2_heavy_alpha5.c"


def _run(cmd, **kw):
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, **kw)
    assert r.returncode == 0, f"{cmd}: {r.stdout[-2000:]} {r.stderr[-2000:]}"
    return r.stdout


@pytest.fixture(scope="module")
def made(exported, prefix):
    if shutil.which("make") is None or shutil.which("c++") is None:
        pytest.skip("make or c++ is not installed")
    out = _run(make_cmd(exported))
    lib = prefix.rstrip("_")
    assert re.search(rf"^compiling lib{lib}\.so \.\.\. \d+ s$", out, re.M), out  # make's progress line
    return exported


@pytest.fixture(scope="module")
def cmake_outputs(exported, tmp_path_factory):
    """Build with CMake, install, build consumer/ against the installed package; run both C++ examples."""
    if shutil.which("cmake") is None or shutil.which("c++") is None:
        pytest.skip("cmake or c++ is not installed")
    w = tmp_path_factory.mktemp("cmake")
    _run(["cmake", "-S", str(exported), "-B", str(w / "build")])
    _run(["cmake", "--build", str(w / "build")])
    _run(["cmake", "--install", str(w / "build"), "--prefix", str(w / "prefix")])
    _run(["cmake", "-S", str(exported / "consumer"), "-B", str(w / "consumer"), f"-DCMAKE_PREFIX_PATH={w / 'prefix'}"])
    _run(["cmake", "--build", str(w / "consumer")])
    return {
        "cmake example": _run([str(w / "build" / "example")], cwd="/"),
        "cmake example_cpp": _run([str(w / "build" / "example_cpp")], cwd="/"),
        "installed consumer example_cpp": _run([str(w / "consumer" / "example_cpp")], cwd="/"),
        "prefix": w / "prefix",
    }


def parse_example(text: str) -> dict[str, dict[str, dict[str, np.ndarray]]]:
    """{function: {"in": {name: values}, "out": {name: values}}} from an example's output lines."""
    res: dict = {}
    for line in text.splitlines():
        m = re.fullmatch(r"(in|out) (\w+) (\w+) :((?: \S+)+)", line)
        assert m, f"unexpected line: {line!r}"
        kind, fn, name, vals = m.groups()
        res.setdefault(fn, {"in": {}, "out": {}})[kind][name] = np.array([float(v) for v in vals.split()])
    return res


def _check_against_vm(text: str, plant, where: str, system):
    got = parse_example(text)
    assert list(got) == list(NAMES), where
    p = system.params.vector()
    ref_inputs = example_inputs(system)
    for fn_name, io in got.items():
        f = plant[fn_name]
        assert list(io["in"]) == [n for n in f.name_in() if n != "p"]
        args = []
        for n in f.name_in():
            if n == "p":
                args.append(p)
            else:
                np.testing.assert_array_equal(io["in"][n], ref_inputs[n])  # %.17g reads back exactly
                args.append(io["in"][n])
        refs = f.call(args)
        assert list(io["out"]) == list(f.name_out())
        for k, r in zip(f.name_out(), refs):
            ref = np.ravel(np.asarray(r), order="F")  # column-major, as the C library stores matrices
            out = io["out"][k]
            assert out.size == ref.size and np.all(np.isfinite(ref)) and np.max(np.abs(ref)) > 0
            np.testing.assert_allclose(out, ref, rtol=RTOL, atol=RTOL * np.max(np.abs(ref)),
                                       err_msg=f"{where}: {fn_name}.{k}")


def test_export_writes_all_files_and_manifest(exported, prefix):
    names = files(prefix)
    for name in names:
        assert (exported / name).is_file() and (exported / name).stat().st_size > 0, name
    m = json.loads((exported / MANIFEST).read_text())
    assert set(m["files"]) == set(names) - {MANIFEST}
    for name, sha in m["files"].items():
        assert hashlib.sha256((exported / name).read_bytes()).hexdigest() == sha, name


def test_make_examples_match_python(made, plant, system):
    c = _run([str(made / "example")], cwd="/")
    cpp = _run([str(made / "example_cpp")], cwd="/")
    py = _run([sys.executable, str(made / "example.py")], cwd="/")
    _check_against_vm(c, plant, "make example (C)", system)
    assert cpp == c  # C++ through the _eval wrappers: the same library, the same bits
    assert py == c  # ctypes
    # and the compiled library gives the bits arvcas.dynamics gives (same flags, same compiler)
    got = parse_example(c)
    e = example_inputs(system)
    assert got["uvms_rhs"]["in"]["q"].size == system.n_joints and got["thrust"]["in"]["u"].size == system.n_thrusters
    np.testing.assert_array_equal(got["uvms_rhs"]["out"]["xdot"], arvcas.dynamics("uvms_rhs", system=system)(
        e["x"], e["tau"], e["q"], e["qd"], e["qdd"], e["payload"]))


def test_cmake_package_builds_and_matches(cmake_outputs, made, plant, system, prefix):
    c = _run([str(made / "example")], cwd="/")
    for key in ("cmake example", "cmake example_cpp", "installed consumer example_cpp"):
        _check_against_vm(cmake_outputs[key], plant, key, system)
        assert cmake_outputs[key] == c, key
    pre = cmake_outputs["prefix"]
    lib = prefix.rstrip("_")
    assert list(pre.glob(f"lib*/cmake/{lib}/{lib}Config.cmake"))
    assert (pre / "include" / f"{lib}.h").is_file() and (pre / "include" / f"{lib}_params.h").is_file()


def test_build_files_use_the_cache_flags(exported, made, monkeypatch, tmp_path, system, prefix):
    cflags = [codegen.DEFAULT_OPT_LEVEL, *codegen.FIXED_FLAGS]
    lib = prefix.rstrip("_")
    dry = _run(["make", "-B", "-n", "-C", str(made)])
    lib_cmd = next(ln for ln in dry.splitlines() if f"-o lib{lib}.so" in ln)
    assert all(f in lib_cmd.split() for f in [*cflags, *codegen.BASE_FLAGS, *codegen.LIBS]), lib_cmd
    cm = (exported / "CMakeLists.txt").read_text()
    assert f"target_compile_options({lib} PRIVATE {' '.join(cflags)})" in cm
    # read from codegen at export time, not copied: a changed FIXED_FLAGS shows up in both files
    monkeypatch.setattr(codegen, "FIXED_FLAGS", (*codegen.FIXED_FLAGS, "-fno-trapping-math"))
    export_c(tmp_path / "other", system=system.params)
    assert "-fno-trapping-math" in (tmp_path / "other" / "Makefile").read_text()
    assert "-fno-trapping-math" in (tmp_path / "other" / "CMakeLists.txt").read_text()


def test_symbols_carry_the_prefix_and_header_declares_them(made, prefix):
    if shutil.which("nm") is None:
        pytest.skip("nm is not installed")
    lib = prefix.rstrip("_")
    out = _run(["nm", "-D", "--defined-only", str(made / f"lib{lib}.so")])
    syms = [ln.split()[-1] for ln in out.splitlines() if ln.split() and ln.split()[-2] in "TDBR"]
    assert len(syms) > 7 * 10
    assert [s for s in syms if not s.startswith(prefix)] == []
    for name in NAMES:
        assert prefix + name in syms
    header = (made / f"{lib}.h").read_text()
    c_text = (made / f"{lib}.c").read_text()
    helpers = {prefix + h for h in re.findall(r"^#define casadi_\w+ CASADI_PREFIX\((\w+)\)$", c_text, flags=re.M)}
    api = set(re.findall(r"^CASADI_SYMBOL_EXPORT [^(]*?\b(\w+)\(", c_text, flags=re.M))
    assert set(syms) <= api | helpers and api <= set(syms)  # CasADi's helpers are global too, prefixed
    for s in sorted(api):  # every function of the API declared exactly once
        decls = re.findall(rf"^\w[^\n]*\b{s}\([^\n]*\);$", header, flags=re.M)  # declarations, not calls
        assert len(decls) == 1, (s, decls)
    # the header's "F returns 0": no other return in the generated evaluation functions
    bodies = re.findall(r"^static int casadi_f\d+\(.*?^}$", c_text, flags=re.M | re.S)
    assert len(bodies) >= len(NAMES)
    assert {r for b in bodies for r in re.findall(r"return [^;]*;", b)} == {"return 0;"}
    # the header agrees with the generated code (conflicting declarations are errors) in C and C++
    _run([codegen.CC, "-std=c99", "-Wall", "-Werror", "-fsyntax-only", "-include", str(made / f"{lib}.h"),
          str(made / f"{lib}.c")])
    _run(["c++", "-Wall", "-Werror", "-fsyntax-only", "-x", "c++", str(made / f"{lib}.h")])


def test_header_documents_every_argument(exported, plant, system, prefix):
    lib = prefix.rstrip("_")
    text = (exported / f"{lib}.h").read_text()
    assert "THREAD SAFETY" in text and "reentrant" in text and "own arg, res, iw and w" in text
    nj, nt = system.n_joints, system.n_thrusters
    # one text for every system: its name, its file's description, its sizes
    assert text.startswith(f"/* {lib}.h: the arvcas plant functions of the system {system.name}, in C:\n"
                           f" * {system.description}\n")
    assert f"{nt} thrusters, {nj} joints" in text and f"q[{nj}], u[{nt}], p[{len(system.params)}]" in text
    if nj != 6:
        assert "q1..q6" not in text and "12 x 6, column-major: d xdot_i / d q_j" not in text
    if nt != 6:
        assert "u[6]" not in text
    for name in NAMES:
        f = plant[name]
        full = prefix + name
        block = text.split(f" * {full}: ", 1)[1].split("*/", 1)[0]
        rows = re.findall(r"^ \*   (arg|res)\[(\d+)\]\s+(\w+)\s+(\S+)  (.+)$", block, flags=re.M)
        expect = [("arg", str(i), f.name_in(i), str(f.numel_in(i))) for i in range(f.n_in())]
        expect += [("res", str(i), f.name_out(i), f"{f.size1_out(i)}x{f.size2_out(i)}" if f.size2_out(i) > 1
                    else str(f.size1_out(i))) for i in range(f.n_out())]
        assert [r[:4] for r in rows] == expect, name
        assert all(len(r[4]) > 10 for r in rows), name  # every argument has a meaning with units
        sizes = {r[2]: r[3] for r in rows}
        assert sizes.get("q", str(nj)) == str(nj) and sizes.get("u", str(nt)) == str(nt), name
        assert sizes["p"] == str(len(system.params)), name
        meaning = {r[2]: r[4] for r in rows}
        if "q" in meaning:
            assert f"q1..q{nj} (rad)" in meaning["q"], name
        if "u" in meaning:
            assert ", ".join(system.structure.thruster_names()) in meaning["u"], name
        sz = {k: int(re.search(rf"#define {full.upper()}_{k} (\d+)", text).group(1)) for k in ("SZ_ARG", "SZ_RES")}
        assert sz["SZ_ARG"] >= f.n_in() and sz["SZ_RES"] >= f.n_out(), name


def test_params_header_is_the_default_vector(exported, system, prefix):
    lib = prefix.rstrip("_")
    text = (exported / f"{lib}_params.h").read_text()
    P = system.params
    names, v = P.names(), P.vector()
    up = prefix.upper()
    assert f"#define {up}NP {len(names)}" in text
    rows = re.findall(r"^\s+(\S+),\s+/\* \[\s*(\d+)\] (\S+)\s+(.*?) \*/$", text, flags=re.M)
    assert [int(i) for _, i, _, _ in rows] == list(range(len(names)))
    assert [n for _, _, n, _ in rows] == names
    assert [float(x) for x, _, _, _ in rows] == list(v)  # exact
    units = {n: u for _, _, n, u in rows}
    assert units["env.rho"] == "kg/m^3" and units["vehicle.m"] == "kg" and units["payload.volume"] == "m^3"
    if system.name == "haidou1":
        assert units["arm.joint1.alpha"] == "rad (file: deg)"
        assert units["hydro.X_u"] == "per_rho"  # per unit density (Table A1)
    else:  # SI hydrodynamic coefficients: the unit of each term
        assert units["arm.joint1.roll"] == "rad (file: deg)" and units["thrusters.T1.u_max"] == "N"
        assert units["hydro.X_udot"] == "kg" and units["hydro.X_u"] == "kg/s" and units["hydro.X_u_absu"] == "kg/m"
        assert units["hydro.K_p_absp"] == "kg*m^2/rad^2" and units["hydro.M_q"] == "kg*m^2/(s*rad)"
    assert f"#define {up}P_ENV_G {names.index('env.g')}" in text


def test_readme_lists_io_from_the_functions(exported, plant, prefix):
    text = (exported / "README.md").read_text()
    for name in NAMES:
        f = plant[name]
        section = text.split(f"### `{prefix}{name}`\n", 1)[1].split("###", 1)[0]
        rows = re.findall(r"^\| (in|out) \| (\d+) \| `(\w+)` \| (\d+)x(\d+)", section, flags=re.M)
        expect = [("in", str(i), f.name_in(i), *map(str, f.size_in(i))) for i in range(f.n_in())]
        expect += [("out", str(i), f.name_out(i), *map(str, f.size_out(i))) for i in range(f.n_out())]
        assert rows == expect, name


def test_export_replaces_only_its_own_unchanged_files(tmp_path, capsys):
    out = tmp_path / "lib"
    export_c(out)
    before = (out / "Makefile").read_text()
    (out / "notes.txt").write_text("mine")
    export_c(out)  # again: every file is arvcas's and unchanged
    assert (out / "Makefile").read_text() == before and (out / "notes.txt").read_text() == "mine"
    (out / "example.c").write_text("/* edited */")
    with pytest.raises(ExportError, match=r"example.c: was changed since arvcas wrote it"):
        export_c(out)
    assert (out / "example.c").read_text() == "/* edited */"
    assert cli.main(["export-c", str(out)]) == 2
    err = capsys.readouterr().err
    # the command line's output policy refuses first (the edited file is no longer the one arvcas wrote)
    assert err.startswith("arvcas: error: ") and "example.c" in err and "--force" in err and err.count("\n") == 1
    assert cli.main(["export-c", str(out), "--force"]) == 0
    assert (out / "example.c").read_text() != "/* edited */"
    capsys.readouterr()
    # a directory with files of someone else's under the names export-c writes
    other = tmp_path / "other"
    other.mkdir()
    (other / "Makefile").write_text("all:\n")
    with pytest.raises(ExportError, match=r"Makefile: exists and was not written by arvcas"):
        export_c(other)
    assert (other / "Makefile").read_text() == "all:\n" and not (other / "example.c").exists()
    (other / "Makefile").unlink()
    (other / MANIFEST).write_text("{not json")  # export-c's own listing: a file like any other
    with pytest.raises(ExportError, match=r"arvcas-export.json: exists and was not written by arvcas"):
        export_c(other)
    (other / MANIFEST).unlink()
    (other / "example.py").symlink_to(tmp_path / "lib" / "example.py")
    with pytest.raises(ExportError, match=r"example.py: exists and was not written"):
        export_c(other)
    export_c(other, force=True)
    assert not (other / "example.py").is_symlink()


def test_prefix_and_reentrancy_checks(tmp_path):
    with pytest.raises(ExportError, match=r"prefix: expected a C identifier ending in one '_'"):
        export_c(tmp_path / "x", prefix="1abc_")
    with pytest.raises(ExportError, match=r"prefix"):
        export_c(tmp_path / "x", prefix="abc")
    paths = export_c(tmp_path / "x", prefix="mine_")
    assert paths[0].name == "mine.c"
    assert "int mine_uvms_rhs(" in paths[0].read_text()
    with pytest.raises(ExportError, match=r"writable global data"):
        _check_reentrant("static double cache[3];\n", [])
    with pytest.raises(ExportError, match=r"manage memory"):
        _check_reentrant("int f_checkout(void) {\n  return counter++;\n}\n", ["f"])


def test_export_refuses_bad_dirs(tmp_path, capsys):
    with pytest.raises(ValueError, match="parent directory .* does not exist"):
        export_c(tmp_path / "missing" / "out")
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(ValueError, match="is not a directory"):
        export_c(a_file)
    assert cli.main(["export-c", str(tmp_path / "missing" / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("arvcas: error: export-c: parent directory") and err.count("\n") == 1
    assert not (tmp_path / "missing").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write to any directory")
def test_export_refuses_read_only_dir(tmp_path):
    d = tmp_path / "ro"
    d.mkdir()
    os.chmod(d, 0o500)
    try:
        with pytest.raises(ValueError, match="not writable"):
            export_c(d)
    finally:
        os.chmod(d, 0o700)


# ---- command line --------------------------------------------------------------------------


def _quintic_ref(t):
    q0 = np.radians([90, 90, -90, 0, 90, 0])
    qg = np.radians([60, 60, -60, 0, 60, 0])
    s = np.clip((t - 5.0) / 15.0, 0, 1)
    pos = 10 * s**3 - 15 * s**4 + 6 * s**5
    vel = (30 * s**2 - 60 * s**3 + 30 * s**4) / 15.0
    acc = (60 * s - 180 * s**2 + 120 * s**3) / 15.0**2
    return q0 + (qg - q0) * pos, (qg - q0) * vel, (qg - q0) * acc


@pytest.fixture(scope="module")
def haidou1_plant():
    fns = dict(uvms.plant_functions(uvms.ModelOptions()))
    fns.update(jacobian_functions(fns))
    return fns


def test_demo_table(cache, haidou1_plant, capsys):
    plant = haidou1_plant
    assert cli.main(["demo"]) == 0
    lines = capsys.readouterr().out.splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.split()[:2] == ["t", "[s]"])
    rows = np.array([[float(v) for v in ln.split()] for ln in lines[head + 1 :]])
    assert rows.shape == (26, 7)
    np.testing.assert_array_equal(rows[:, 0], np.arange(26.0))
    p, z = load().vector(), np.zeros(6)
    for t in (0.0, 8.0, 12.0, 17.0, 25.0):
        q, qd, qdd = _quintic_ref(t)
        ref = np.asarray(plant["arm_wrench"](z, z, z, q, qd, qdd, 0, p)).ravel()
        np.testing.assert_allclose(rows[int(t), 1:], ref, atol=6e-5, err_msg=f"t = {t}")
    assert rows[0, 3] > 0  # at rest and level the arm's weight in water pushes the vehicle down (+z)


def test_cache_command(cache, haidou1_plant, capsys):
    plant = haidou1_plant
    from arvcas.build.codegen import build

    build(plant["arm_wrench"])  # into this module's cache (compiled() may be memoized from elsewhere)
    assert cli.main(["cache"]) == 0
    out = capsys.readouterr().out
    assert f"cache: {cache}" in out
    assert re.search(r"^arm_wrench\s+\d+\.\d\s+\d+\.\d\d\s+yes\s+", out, flags=re.M), out


def test_errors_are_one_line_exit_2(tmp_path, monkeypatch, capsys):
    cases = [
        (["demo", "--params", str(tmp_path / "nope.toml")], "nope.toml: file not found"),
        (["demo", "--n-quad", "0"], "--n-quad: 0 is out of range"),
    ]
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)
    for argv, what in cases:
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("arvcas: error: ") and what in err and err.count("\n") == 1, err
        assert "Traceback" not in err
    monkeypatch.setenv("ARVCAS_CACHE", str(shared))
    assert cli.main(["cache"]) == 2
    err = capsys.readouterr().err
    assert err == f"arvcas: error: cache directory {shared} is writable by group or others (mode 777); " \
                  f"fix it with: chmod go-w {shared}\n"


def test_usage_errors_exit_2(capsys):
    assert cli.main(["no-such-command"]) == 2
    assert "invalid choice" in capsys.readouterr().err
    assert cli.main([]) == 2
    assert cli.main(["--help"]) == 0
    assert set(cli.COMMANDS) >= {"export-c", "cache", "demo"}
