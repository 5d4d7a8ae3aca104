"""A compiled function's library is keyed by its C: two descriptions that give the same C share one library
(compiled once), a description whose C differs gets its own, and a description's manifest never makes a
library load that does not verify against its own manifest."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import casadi as ca
import pytest

from arvcas.build import codegen


def _fn(name: str, k: float) -> ca.Function:
    x = ca.SX.sym("x", 3)
    return ca.Function(name, [x], [ca.sin(x) * k + ca.dot(x, x)])


def _new_process() -> None:
    """Forget what this process loaded (as a new process would), keeping the disk cache."""
    codegen._DESCRIBED.clear()
    codegen._DIGESTS.clear()
    codegen._MADE.clear()


def _compiles() -> int:
    return codegen.stats()["compile"]


def test_two_descriptions_of_the_same_c_compile_once(cache):
    made = []

    def make():
        made.append(1)
        return _fn("keys_same", 2.0)

    n0 = _compiles()
    f = codegen.build_described("keys_same", "scenario A (a field the graph ignores = 1)", make)
    assert _compiles() == n0 + 1
    g = codegen.build_described("keys_same", "scenario B (a field the graph ignores = 2)", make)
    assert _compiles() == n0 + 1, "the same C was compiled again under another description"
    assert len(made) == 2  # each description built its graph once
    ma, mb = codegen.artifact_of(f), codegen.artifact_of(g)
    assert ma["path"] == mb["path"] and ma["key"] == mb["key"] and ma["c_sha256"] == mb["c_sha256"]
    assert ma["described_key"] != mb["described_key"]
    assert float(g(ca.DM([1, 2, 3]))[0]) == float(_fn("x", 2.0)(ca.DM([1, 2, 3]))[0])

    _new_process()  # a warm start: each description loads the shared library without building a graph
    h = codegen.build_described("keys_same", "scenario B (a field the graph ignores = 2)",
                                lambda: pytest.fail("built a graph on a warm start"))
    assert codegen.artifact_of(h)["path"] == ma["path"] and _compiles() == n0 + 1
    assert codegen.described_digest("keys_same", "scenario A (a field the graph ignores = 1)",
                                    lambda: pytest.fail("built a graph")) == ma["c_sha256"]


def test_a_description_whose_c_differs_gets_its_own_library(cache):
    n0 = _compiles()
    f = codegen.build_described("keys_differ", "k=2", lambda: _fn("keys_differ", 2.0))
    g = codegen.build_described("keys_differ", "k=3", lambda: _fn("keys_differ", 3.0))
    assert _compiles() == n0 + 2
    assert codegen.artifact_of(f)["path"] != codegen.artifact_of(g)["path"]
    x = ca.DM([0.5, -1.0, 2.0])
    assert float(f(x)[0]) == float(_fn("a", 2.0)(x)[0]) and float(g(x)[0]) == float(_fn("b", 3.0)(x)[0])


def test_a_library_of_the_same_c_built_by_build_is_shared(cache):
    n0 = _compiles()
    f = codegen.build(_fn("keys_shared", 5.0))
    g = codegen.build_described("keys_shared", "built by build() first", lambda: _fn("keys_shared", 5.0))
    assert _compiles() == n0 + 1
    assert codegen.artifact_of(f)["path"] == codegen.artifact_of(g)["path"]


def _description_manifest(cache, name: str) -> tuple[dict, object]:
    mans = [p for p in cache.glob(f"{name}-*.json") if "library_key" in json.loads(p.read_text())]
    assert len(mans) == 1
    return json.loads(mans[0].read_text()), mans[0]


def test_a_stale_or_foreign_library_is_never_loaded_through_a_description(cache):
    f = codegen.build_described("keys_trust", "trust", lambda: _fn("keys_trust", 7.0))
    lib = codegen.artifact_of(f)["path"]
    m, man = _description_manifest(cache, "keys_trust")
    assert m["library_key"] == codegen.artifact_of(f)["key"]

    # the library's bytes changed: it no longer matches its own manifest, so it is rebuilt, not loaded
    _new_process()
    with open(lib, "ab") as fh:
        fh.write(b"tampered")
    n0 = _compiles()
    g = codegen.build_described("keys_trust", "trust", lambda: _fn("keys_trust", 7.0))
    assert _compiles() == n0 + 1 and codegen.stats()["rejected"] >= 1
    assert codegen.artifact_of(g)["so_sha256"] != "" and float(g(ca.DM([1, 1, 1]))[0]) == float(
        _fn("r", 7.0)(ca.DM([1, 1, 1]))[0])

    # a description manifest pointing at a library that is not there (or not a key): built again, not loaded
    for bad in ("0" * 64, "../../etc/passwd", 42):
        _new_process()
        man.write_text(json.dumps(dict(m, library_key=bad)))
        n0 = _compiles()
        hit = codegen.stats()["disk_hit"]
        h = codegen.build_described("keys_trust", "trust", lambda: _fn("keys_trust", 7.0))
        assert codegen.stats()["disk_hit"] == hit + 1 and _compiles() == n0  # the library of its C, found by the C
        assert json.loads(man.read_text())["library_key"] == m["library_key"]  # the manifest is written again
        assert codegen.artifact_of(h)["path"] == lib


def test_a_new_process_shares_the_library_of_the_same_c(cache):
    """Two processes, two descriptions of one C: the second compiles nothing."""
    script = textwrap.dedent("""
        import sys, casadi as ca
        from arvcas.build import codegen
        x = ca.SX.sym("x", 3)
        f = codegen.build_described("keys_proc", sys.argv[1], lambda: ca.Function("keys_proc", [x], [ca.cos(x) * 3]))
        print(codegen.stats()["compile"], codegen.artifact_of(f)["path"])
    """)
    env = dict(os.environ, ARVCAS_CACHE=str(cache))
    out = [subprocess.run([sys.executable, "-c", script, d], env=env, capture_output=True, text=True, check=True)
           .stdout.split() for d in ("first description", "second description")]
    assert out[0][0] == "1" and out[1][0] == "0" and out[0][1] == out[1][1]


def test_a_shipped_library_is_used_whatever_the_workers_level(cache, tmp_path, monkeypatch):
    """A bundle's library is known by what its caller asked for (the default level), not by the level that
    default is where it lands: a worker with another ``ARVCAS_OPT_LEVEL`` and ``ARVCAS_ISA`` uses what it was
    shipped (its manifest says how it was built); a worker asking for a level by name gets that level."""
    from arvcas.build import shipping

    f = codegen.build_described("keys_ship", "shipped", lambda: _fn("keys_ship", 4.0))
    client_flags = codegen.artifact_of(f)["flags"]
    b = shipping.bundle([f])
    worker_cache = tmp_path / "worker-cache"
    worker_cache.mkdir(mode=0o700)
    level = "-O3" if codegen.default_opt_level() != "-O3" else "-O1"
    monkeypatch.setenv("ARVCAS_OPT_LEVEL", level)
    monkeypatch.setenv("ARVCAS_ISA", "baseline")
    monkeypatch.setenv("ARVCAS_CACHE", str(worker_cache))
    monkeypatch.setattr(codegen, "_PRELOADED", {})
    _new_process()
    assert shipping.preload(b) == 1
    n0 = _compiles()
    g = codegen.build_described("keys_ship", "shipped", lambda: pytest.fail("the worker built what it was shipped"))
    assert codegen.artifact_of(g)["flags"] == client_flags and codegen.artifact_of(g).get("shipped")
    assert codegen.described_digest("keys_ship", "shipped", lambda: pytest.fail("built a graph")) == \
        codegen.artifact_of(f)["c_sha256"]
    h = codegen.build_described("keys_ship", "shipped", lambda: _fn("keys_ship", 4.0), opt_level=level)
    assert _compiles() == n0 + 1 and level in codegen.artifact_of(h)["flags"]


def test_every_system_is_named_in_its_compile_descriptions():
    """The default system takes the same path as any other: its runs' and tables' descriptions name it."""
    from arvcas.system import DEFAULT, load_system, shipped
    from arvcas.system.params import system_tag

    assert DEFAULT in shipped()
    for name in shipped():
        tag = system_tag(load_system(name).structure)
        assert tag.startswith(" system=") and f"name='{name}'" in tag, (name, tag[:80])
