"""A front is valid while its compiled run is: the run digest (the sha256 of the C that CasADi generates
for the run function and its time table) is the same in every process, is answered by the compile
cache without compiling, stays the same under an edit of arvcas that leaves the run's arithmetic alone
(even one that changes the source hash), changes under one that does not; ``front restamp`` stamps a
front only when every member replays bit for bit, and never alters a stored number."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import casadi as ca
import h5py
import numpy as np
import pytest

from arvcas.build import codegen
from arvcas.build.provenance import model_hash
from arvcas.sim.simulation import compiled_run
from arvcas.system.params import load
from arvcas.tuning import checkpoint as ck
from arvcas.tuning import front as front_mod
from arvcas.tuning import load_study, run_study

from test_tuning_study import write_tiny
from trust_helpers import assert_refused, run3, synthetic_front

PKG = Path(codegen.__file__).resolve().parents[1]
OLD = "0" * 64
_DIGEST = ("import arvcas; from arvcas.sim.simulation import compiled_run; "
           "print(arvcas.__file__, compiled_run('agsta').digest())")


def _digest_in_fresh_process(pythonpath: Path, cache: Path) -> str:
    env = dict(os.environ, PYTHONPATH=str(pythonpath), ARVCAS_CACHE=str(cache))
    out = subprocess.run([sys.executable, "-c", _DIGEST], env=env, cwd=pythonpath, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    where, digest = out.stdout.strip().splitlines()[-1].split()
    assert Path(where).is_relative_to(pythonpath), where  # the copy's arvcas, not this tree's
    return digest


def _tree(tmp_path: Path, name: str, edit=None) -> Path:
    """A copy of the arvcas package under tmp_path/name, with ``edit(root)`` applied."""
    root = tmp_path / name
    shutil.copytree(PKG, root / "arvcas", ignore=shutil.ignore_patterns("__pycache__"))
    if edit is not None:
        edit(root / "arvcas")
    return root


def _replace(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert text.count(old) == 1, (path, old)
    path.write_text(text.replace(old, new))


def test_described_digest_compiles_nothing_and_equals_the_manifest(cache):
    x = ca.SX.sym("x", 2)
    made = []

    def make():
        made.append(1)
        return ca.Function("digest_probe", [x], [ca.sin(x) * 3.0 + x[0]])

    before = codegen.stats()["compile"]
    d = codegen.described_digest("digest_probe", "digest probe 1", make)
    assert codegen.stats()["compile"] == before and len(d) == 64
    f = codegen.build_described("digest_probe", "digest probe 1", make)
    assert codegen.stats()["compile"] == before + 1 and len(made) == 1  # the digest's graph was compiled
    assert codegen.digest_of(f) == d == codegen.artifact_of(f)["c_sha256"]
    codegen._DIGESTS.clear()  # a new process: the cache's manifest answers, make() is not called
    assert codegen.described_digest("digest_probe", "digest probe 1", lambda: pytest.fail("built a graph")) == d


def test_the_run_digest_follows_the_run_not_the_source(tmp_path, cache):
    """Two fresh processes agree; a comment in a model file (new source hash) keeps the digest; a changed
    coefficient in the vehicle's damping (a model function) changes it, and a front stamped with the old digest
    is then refused while one stamped with today's is accepted whatever its source hash."""
    same = _tree(tmp_path, "same")
    comment = _tree(tmp_path, "comment", lambda a: _replace(a / "model" / "manipulator.py", "k = -0.5 * rho * Cd * D_i",
                                                             "k = -0.5 * rho * Cd * D_i  # a comment"))
    drag = _tree(tmp_path, "drag", lambda a: _replace(a / "model" / "vehicle.py", "ca.mtimes(D(P, nu), nu)",
                                                       "1.0000001 * ca.mtimes(D(P, nu), nu)"))
    digests = {n: _digest_in_fresh_process(root, tmp_path / f"cache-{n}")
               for n, root in (("same", same), ("same2", same), ("comment", comment), ("drag", drag))}
    here = compiled_run("agsta").digest()
    assert digests["same"] == digests["same2"] == digests["comment"] == here, digests
    assert digests["drag"] != here, digests

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    valid = synthetic_front(tmp_path / "a" / "front.h5", model_hash=OLD, run_digest=here)
    assert front_mod.check_provenance(valid, load(), False, "replay") == ""
    stale = synthetic_front(tmp_path / "b" / "front.h5", run_digest=digests["drag"])
    with pytest.raises(ck.CheckpointError, match=r"the compiled run changed \(run digest " + digests["drag"][:12]):
        front_mod.check_provenance(stale, load(), False, "replay")


def test_an_older_file_is_refused_in_one_line_saying_how_to_restamp(tmp_path, capsys):
    old = synthetic_front(tmp_path / "front.h5", model_hash=OLD)
    err = assert_refused(["front", "explore", old, "--out", tmp_path / "x.html"], capsys, tmp_path,
                         f"re-stamp it: arvcas front restamp {old}")
    assert "records only the hash of the source that wrote it (model hash 000000000000" in err
    assert "a re-run would not reproduce" not in err  # not known: it may well replay
    same_source = synthetic_front(tmp_path / "same.h5")  # today's source hash, no digest: valid
    assert front_mod.check_provenance(same_source, load(), False, "replay") == ""


@pytest.fixture(scope="module")
def tiny_front(tmp_path_factory):
    d = tmp_path_factory.mktemp("restamp")
    run_study(load_study(write_tiny(d / "s.toml")), d / "out", say=lambda m: None, stop_after=1)
    return d / "out" / "front.h5"


def _arrays(path: Path) -> dict:
    """Every dataset of a file, as bytes (strings as their values)."""
    out = {}

    def keep(name, obj):
        if isinstance(obj, h5py.Dataset):
            v = np.asarray(obj[()])
            out[name] = repr(v.tolist()) if v.dtype.kind == "O" else v.tobytes()

    with h5py.File(path, "r") as f:
        f.visititems(keep)
    return out


def test_restamp_stamps_a_front_that_replays_bit_for_bit(tiny_front, tmp_path, capsys):
    path = tmp_path / "front.h5"
    shutil.copy(tiny_front, path)
    today = ck.read_checkpoint(path).run_digest
    assert len(today) == 64
    with h5py.File(path, "r+") as f:  # as written by an older arvcas: a source hash and no digest
        del f.attrs["run_digest"]
        f.attrs["model_hash"] = OLD
    data, updated = _arrays(path), ck.read_checkpoint(path).updated
    rc, out, err = run3(["front", "restamp", path, "--check"], capsys)
    assert rc == 1 and "replayed bit for bit" in out and "its run digest is not today's" in out, (out, err)
    rc, out, err = run3(["front", "restamp", path], capsys)
    assert rc == 0 and out.startswith("re-stamped ") and "and the default gains: replayed bit for bit" in out, err
    c = ck.read_checkpoint(path)
    assert c.run_digest == today and c.model_hash == OLD and c.updated == updated
    assert len(c.restamps) == 1 and c.restamps[0]["model_hash"] == model_hash()
    assert _arrays(path) == data  # not one stored number changed
    assert front_mod.check_provenance(path, load(), False, "replay") == ""
    rc, out, err = run3(["front", "restamp", path, "--check"], capsys)
    assert rc == 0 and out.startswith("ok "), (out, err)


def test_restamp_refuses_a_front_that_does_not_replay(tiny_front, tmp_path, capsys):
    path = tmp_path / "front.h5"
    shutil.copy(tiny_front, path)
    with h5py.File(path, "r+") as f:
        del f.attrs["run_digest"]
        f.attrs["model_hash"] = OLD
        i = int(f["front/index"][0])
        F = f["population/F"][()]
        F[i, 0] = np.nextafter(F[i, 0], np.inf)  # one ulp off
        f["population/F"][...] = F
    before = path.read_bytes()
    rc, out, err = run3(["front", "restamp", path], capsys)
    assert rc == 1 and out.startswith("FAILED front restamp: ") and "not re-stamped; re-run the study" in out, out
    assert "max |difference| " in out and " in the objectives, 0 in the per-DOF CHAT/RMSE" in out, out
    assert path.read_bytes() == before
