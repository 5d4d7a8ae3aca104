"""A warm start loads compiled libraries by their description without building any graph, and the
description key never goes stale: editing model code, the data file or an option rebuilds.

Each case runs in a fresh process on a private copy of the package (so the tests may edit it) and a
private compile cache. The plant function ``thrust`` stands in for every described build (its key is
made the same way as the run's: description + the package's model hash + toolchain); the last test
shows the full closed-loop run starts warm with its graph builder disabled.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import arvcas

PKG = Path(arvcas.__file__).resolve().parent

CHILD = """
import json
from arvcas.build import codegen as C
from arvcas.build.dynamics import compiled
from arvcas.model import uvms
def no_graph(*a, **k):
    raise AssertionError("a warm start built a graph")
if {forbid_graph!r}:
    uvms.plant_functions = no_graph
f = compiled("thrust", uvms.ModelOptions(n_quad={n_quad}))
print(json.dumps({{"stats": C.stats(), "path": C.artifact_of(f)["path"],
                  "tau": [float(v) for v in f([10, 20, 30, 40, 50, 60], __import__("arvcas.system.params").system.params.load().vector()).full().ravel()]}}))
"""


def child(root: Path, cache: Path, forbid_graph=False, n_quad=5) -> dict:
    env = dict(os.environ, ARVCAS_CACHE=str(cache), PYTHONPATH=str(root))
    code = textwrap.dedent(CHILD.format(forbid_graph=forbid_graph, n_quad=n_quad))
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300, cwd=root)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.fixture
def copy(tmp_path):
    root = tmp_path / "src"
    shutil.copytree(PKG, root / "arvcas", ignore=shutil.ignore_patterns("__pycache__"))
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    return root, cache


def test_the_child_runs_the_copy(copy):
    root, cache = copy
    out = child(root, cache)
    assert out["path"].startswith(str(cache))
    r = subprocess.run([sys.executable, "-c", "import arvcas; print(arvcas.__file__)"], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(root)), cwd=root)
    assert r.stdout.strip().startswith(str(root))


def test_warm_start_builds_no_graph_and_edits_find_the_library_by_its_c(copy):
    root, cache = copy
    cold = child(root, cache)
    assert cold["stats"]["compile"] == 1
    warm = child(root, cache, forbid_graph=True)  # plant_functions would raise: the library is loaded by key
    assert warm["stats"] == {**warm["stats"], "compile": 0, "disk_hit": 1}
    assert warm["path"] == cold["path"] and warm["tau"] == cold["tau"]

    # an edit of model code (even a comment) changes the run's description key: the graph is built again
    # (forbidden, it fails), its C generated and, being the same C, found by the C's own key: no compile, the
    # same library (the cache keys a library by its C: docs/provenance.md)
    with open(root / "arvcas" / "model" / "thrusters.py", "a") as f:
        f.write("\n# edited by a test\n")
    with pytest.raises(AssertionError, match="a warm start built a graph"):
        child(root, cache, forbid_graph=True)
    edited = child(root, cache)
    assert edited["stats"]["compile"] == 0 and edited["path"] == cold["path"] and edited["tau"] == cold["tau"]
    assert child(root, cache, forbid_graph=True)["stats"]["compile"] == 0  # the edited description is warm now

    # an edit of the data file: the parameters are the function's input, not its C
    with open(root / "arvcas" / "data" / "haidou1.toml", "a") as f:
        f.write("\n# edited by a test\n")
    data = child(root, cache)
    assert data["stats"]["compile"] == 0 and data["path"] == cold["path"]

    # another model option that the thrust map does not read (the links' drag quadrature): another
    # description, the same C, the same library; then warm under its own description
    opt = child(root, cache, n_quad=6)
    assert opt["stats"]["compile"] == 0 and opt["path"] == data["path"]
    assert child(root, cache, n_quad=6, forbid_graph=True)["stats"]["compile"] == 0
    # (a description whose C differs compiles its own library: tests/test_compile_keys.py)


def test_closed_loop_run_warm_start_builds_no_graph():
    """The packaged run, warm in the session's cache: a fresh process simulates with the graph builder
    disabled and gets the parent's numbers bit for bit."""
    r0 = arvcas.simulate("pid", seed=2)  # builds (or loads) the trace run and the time table here
    code = textwrap.dedent("""
        import json
        from arvcas.sim import closedloop
        from arvcas.model import uvms
        def no_graph(*a, **k):
            raise AssertionError("a warm start built a graph")
        closedloop.build_run = no_graph
        uvms.plant_functions = no_graph
        import arvcas
        from arvcas.build import codegen as C
        r = arvcas.simulate("pid", seed=2)
        print(json.dumps({"stats": C.stats(), "chat": [float(v) for v in r.chat]}))
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["stats"]["compile"] == 0 and out["stats"]["disk_hit"] >= 1
    assert out["chat"] == [float(v) for v in r0.chat]
