"""No traceback: a full disk, a demo of a system without an arm or a default scenario, a system without a
gain table, a cached library tampered with and re-signed, a checkpoint whose population is corrupt each
give one line (or are repaired), and the last good file is kept."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np

from arvcas.system import shipped

from trust_helpers import assert_refused, snapshot, synthetic_front

FULL_DISK = r'''
import resource, signal, sys
from pathlib import Path
sys.path.insert(0, sys.argv[2])
from trust_helpers import synthetic_front
from arvcas import cli
from arvcas.tuning import checkpoint as ck
d = Path(sys.argv[1])
front = synthetic_front(d / "front.h5")
cli.main(["simulate", "--controller", "pid", "--out", str(d / "run.h5")])  # a result file, before the disk fills
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (16384, 16384))  # every file of this process: at most 16 KiB
try:
    ck.write_checkpoint(ck.read_checkpoint(front), front)
except ck.CheckpointError as e:
    print("checkpoint:", e)
print("rc", cli.main(["simulate", "--controller", "pid", "--out", str(d / "run.h5")]))
'''


def test_a_full_disk_is_one_line_and_keeps_the_last_good_files(tmp_path):
    """h5py's failed writes came out as RuntimeError tracebacks while closing the file, then a crash."""
    r = subprocess.run([sys.executable, "-c", FULL_DISK, str(tmp_path), str(Path(__file__).parent)],
                       capture_output=True, text=True, timeout=300)
    before = {k: v for k, v in snapshot(tmp_path).items() if not k.startswith(".")}
    assert r.returncode == 0, r.stderr[-3000:]
    assert "Traceback" not in r.stderr and "Exception ignored" not in r.stderr, r.stderr[-3000:]
    out = r.stdout.splitlines()
    assert any(ln.startswith("checkpoint: ") and "write failed (File too large); the previous one is kept" in ln
               for ln in out), out
    assert "rc 2" in out and r.stderr.count("arvcas: error: ") == 1 and "write failed" in r.stderr, r.stderr
    from arvcas.tuning import checkpoint as ck

    assert ck.read_checkpoint(tmp_path / "front.h5").n_gen == 1  # the last good checkpoint
    assert not [n for n in os.listdir(tmp_path) if ".arvcas-tmp-" in n]
    assert before and all((tmp_path / k).stat().st_size > 16384 for k in ("front.h5", "run.h5"))


def _system(tmp_path: Path, drop: tuple[str, ...] = (), no_arm: bool = False) -> Path:
    src = shipped()["bluerov2_heavy_alpha5"]
    text = src.read_text()
    if no_arm:
        text = text[:text.index("\n[arm")] + "\n" + text[text.index("\n[defaults]"):]
    for key in drop:
        text = "\n".join(ln for ln in text.splitlines() if not ln.startswith(f"{key} = "))
    text = text.replace('"bluerov2_heavy_alpha5.', f'"{src.parent}/bluerov2_heavy_alpha5.')
    p = tmp_path / f"s{len(list(tmp_path.glob('s*.toml')))}.toml"
    p.write_text(text)
    return p


def test_demo_and_defaults_refused_in_one_line(tmp_path, capsys):
    cases = [
        (["demo", "--system", _system(tmp_path, ("scenario", "gains"), no_arm=True)], "has no arm"),
        (["demo", "--system", _system(tmp_path, ("scenario",))], "names no default scenario"),
        (["simulate", "--controller", "pid", "--system", _system(tmp_path, ("gains",))], "names no gain table"),
    ]
    for argv, message in cases:
        assert_refused(argv, capsys, tmp_path, message)


TAMPERED = r"""
import casadi as ca
from arvcas.build import codegen
x = ca.SX.sym("x")
g = codegen.build(ca.Function("trust_tampered", [x], [3 * x]))
print(float(g(2.0)), codegen.stats()["rejected"], codegen.stats()["compile"])
"""


def test_a_cached_library_tampered_with_and_re_signed_is_rebuilt(tmp_path, monkeypatch):
    """A library that verifies against its (re-signed) manifest but does not load: the next process
    rebuilds it (ca.external's failure was a traceback)."""
    import casadi as ca

    from arvcas.build import codegen

    monkeypatch.setenv("ARVCAS_CACHE", str(tmp_path / "cache"))
    x = ca.SX.sym("x")
    so = Path(codegen.artifact_of(codegen.build(ca.Function("trust_tampered", [x], [3 * x])))["path"])
    junk = so.with_name("junk")
    junk.write_bytes(b"\x7fELF but not a library")
    os.chmod(junk, 0o755)
    os.replace(junk, so)  # tampered with (a new file: this process keeps its mapping) ...
    man = so.with_suffix(".json")
    m = json.loads(man.read_text())
    m["so_sha256"] = hashlib.sha256(so.read_bytes()).hexdigest()
    man.write_text(json.dumps(m))  # ... and re-signed: the manifest verifies it
    r = subprocess.run([sys.executable, "-c", TAMPERED], capture_output=True, text=True, timeout=300,
                       env=dict(os.environ, ARVCAS_CACHE=str(tmp_path / "cache")))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert r.stdout.split() == ["6.0", "1", "1"], r.stdout  # the value, one rejected, one rebuilt
    assert "does not load" in r.stderr and "rebuilding" in r.stderr


def test_a_corrupt_population_is_refused_on_resume(tmp_path, capsys):
    from test_tuning_study import write_tiny

    study = write_tiny(tmp_path / "tiny.toml")
    out = tmp_path / "out"
    out.mkdir()
    front = synthetic_front(out / "front.h5")
    with h5py.File(front, "r+") as f:
        X = f["population/X"][()]
        X[1, 2] = np.nan
        f["population/X"][...] = X
    assert_refused(["tune", study, "--out", out, "--resume"], capsys, tmp_path, "population/X: not finite")
