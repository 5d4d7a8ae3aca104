"""``arvcas export-c`` end to end (export, make, run the example, compare with CasADi's VM to 1e-12
relative) and the ``arvcas`` command line: one-line errors with exit code 2, ``cache``, ``demo``.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from arvcas import cli
from arvcas.model import uvms
from arvcas.build.export import FILES, example_inputs, export_c
from arvcas.params import load

RTOL = 1e-12


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    d = tmp_path_factory.mktemp("arvcas-cache")
    os.chmod(d, 0o700)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ARVCAS_CACHE", str(d))
        yield d


@pytest.fixture(scope="module")
def plant():
    return uvms.plant_functions(uvms.ModelOptions())


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("export") / "plant_c"
    assert cli.main(["export-c", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def example_output(exported):
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    r = subprocess.run(["make", "-C", str(exported)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run([str(exported / "example")], capture_output=True, text=True, timeout=60, cwd="/")
    assert r.returncode == 0, r.stderr
    return r.stdout


def parse_example(text: str) -> dict[str, dict[str, dict[str, np.ndarray]]]:
    """{function: {"in": {name: values}, "out": {name: values}}} from example's output lines."""
    res: dict = {}
    for line in text.splitlines():
        m = re.fullmatch(r"(in|out) (\w+) (\w+) :((?: \S+)+)", line)
        assert m, f"unexpected line: {line!r}"
        kind, fn, name, vals = m.groups()
        res.setdefault(fn, {"in": {}, "out": {}})[kind][name] = np.array([float(v) for v in vals.split()])
    return res


def test_export_writes_all_files(exported):
    for name in FILES:
        assert (exported / name).is_file() and (exported / name).stat().st_size > 0, name


def test_example_matches_python(example_output, plant):
    got = parse_example(example_output)
    assert list(got) == list(uvms.PUBLIC_FUNCTIONS)
    p = load().vector()
    ref_inputs = example_inputs()
    for fn_name, io in got.items():
        f = plant[fn_name]
        assert list(io["in"]) == [n for n in f.name_in() if n != "p"]
        args = []
        for n in f.name_in():
            if n == "p":
                args.append(p)
            else:
                assert io["in"][n].size == f.numel_in(f.index_in(n))
                np.testing.assert_array_equal(io["in"][n], ref_inputs[n])  # %.17g reads back exactly
                args.append(io["in"][n])
        ref = np.asarray(f(*args)).ravel()
        out = io["out"][f.name_out(0)]
        assert out.size == ref.size and np.all(np.isfinite(ref)) and np.max(np.abs(ref)) > 0
        np.testing.assert_allclose(out, ref, rtol=RTOL, atol=RTOL * np.max(np.abs(ref)), err_msg=fn_name)


def test_params_header_is_the_default_vector(exported):
    text = (exported / "params_default.h").read_text()
    P = load()
    names, v = P.names(), P.vector()
    assert f"#define ARVCAS_NP {len(names)}" in text
    rows = re.findall(r"^\s+(\S+),\s+/\* \[\s*(\d+)\] (\S+)\s+(.*?) \*/$", text, flags=re.M)
    assert [int(i) for _, i, _, _ in rows] == list(range(len(names)))
    assert [n for _, _, n, _ in rows] == names
    assert [float(x) for x, _, _, _ in rows] == list(v)  # exact
    units = {n: u for _, _, n, u in rows}
    assert units["env.rho"] == "kg/m^3"
    assert units["arm.joint1.alpha"] == "rad (file: deg)"
    assert f"#define ARVCAS_P_ENV_G {names.index('env.g')}" in text


def test_readme_lists_io_from_the_functions(exported, plant):
    text = (exported / "README.md").read_text()
    for name in uvms.PUBLIC_FUNCTIONS:
        f = plant[name]
        section = text.split(f"### `{name}`", 1)[1].split("###", 1)[0]
        rows = re.findall(r"^\| (in|out) \| (\d+) \| `(\w+)` \| (\d+)x(\d+)", section, flags=re.M)
        expect = [("in", str(i), f.name_in(i), *map(str, f.size_in(i))) for i in range(f.n_in())]
        expect += [("out", str(i), f.name_out(i), *map(str, f.size_out(i))) for i in range(f.n_out())]
        assert rows == expect, name


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


def test_demo_table(cache, plant, capsys):
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


def test_cache_command(cache, plant, capsys):
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
