"""The study loop: resume is bit-identical (stop, SIGKILL, SIGINT), lock, atomic checkpoints,
infeasible candidates as constraint violations."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from arvcas import cli
from arvcas.controllers.gains import default_gains
from arvcas.util.files import TMP_MARK
from arvcas.tuning import load_study, run_study
from arvcas.tuning import checkpoint as ck
from arvcas.tuning.engines import LocalEngine
from arvcas.tuning.problem import INFEASIBLE_F, GainProblem
from arvcas.tuning.run import eval_task, evaluate_gains

from test_tuning_study import write_tiny

GENS = 4
POP_FIELDS = ("X", "gains", "F", "G", "rank", "crowding", "chat", "rmse", "ok", "t_fail")


def quiet(_msg: str) -> None:
    pass


def assert_same_study(a: ck.Checkpoint, b: ck.Checkpoint) -> None:
    for k in POP_FIELDS:
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert a.rng_state == b.rng_state and a.n_gen == b.n_gen and a.n_eval == b.n_eval
    for k in ("gen", "n_eval", "n_feasible", "hv", "best_chat", "best_rmse"):
        np.testing.assert_array_equal(a.history[k], b.history[k], err_msg=k)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted tiny study (agsta, population 8, 4 generations)."""
    d = tmp_path_factory.mktemp("tuning_ref")
    study = write_tiny(d / "tiny.toml", generations=GENS)
    out = d / "out"
    res = run_study(load_study(study), out, say=quiet)
    assert res[0].status == "finished" and res[0].n_gen == GENS
    return study, ck.read_checkpoint(out / "front.h5")


@pytest.mark.floor  # pymoo's bounds (pyproject.toml): a study, its front file (h5py)
def test_reference_study_is_complete(reference):
    _, c = reference
    assert c.status == "finished" and c.n_eval == 8 * GENS and c.X.shape == (8, 48)
    np.testing.assert_array_equal(c.gains, 10.0 ** c.X)
    assert c.front.size >= 1 and np.isfinite(c.F[c.front]).all()
    assert c.table2_F.shape == (2,) and c.history["hv"].shape == (GENS,)
    assert np.all(np.diff(c.history["hv"]) >= 0)  # elitist: the front's hypervolume never drops
    assert "tiny" in c.study_text and c.seed == 3 and c.versions["pymoo"]
    feas = c.G[:, 0] <= 0
    assert np.isnan(c.F[~feas]).all() and np.isfinite(c.F[feas]).all()


@pytest.mark.floor  # a resume writes pymoo's private state back (tuning/run.py, _restore)
@pytest.mark.parametrize("stop_at", [1, 2])
def test_resume_after_stop_is_identical(reference, tmp_path, stop_at):
    study, ref = reference
    s = load_study(study)
    out = tmp_path / "out"
    r = run_study(s, out, say=quiet, stop_after=stop_at)
    assert r[0].status == "interrupted" and r[0].n_gen == stop_at
    with pytest.raises(ValueError, match="a study checkpoint exists; continue it with --resume"):
        run_study(s, out, say=quiet)
    r = run_study(s, out, say=quiet, resume=True)
    assert r[0].status == "finished"
    assert_same_study(ref, ck.read_checkpoint(out / "front.h5"))
    # resuming a finished study does nothing
    r = run_study(s, out, say=quiet, resume=True)
    assert r[0].status == "finished" and r[0].n_gen == GENS


def test_resume_with_a_different_study_is_refused_but_longer_termination_continues(reference, tmp_path):
    study, ref = reference
    out = tmp_path / "out"
    run_study(load_study(write_tiny(tmp_path / "short.toml", generations=2)), out, say=quiet)
    changed = write_tiny(tmp_path / "changed.toml", generations=GENS, population=10)
    with pytest.raises(ValueError, match=r"--resume: .* differs from the study in .* in algorithm"):
        run_study(load_study(changed), out, say=quiet, resume=True)
    run_study(load_study(study), out, say=quiet, resume=True)  # only the termination changed
    assert_same_study(ref, ck.read_checkpoint(out / "front.h5"))


def default_signals() -> None:
    """In a child: SIGHUP and SIGTERM at their defaults, as from a user's shell (a test run under nohup
    would otherwise hand its children an ignored SIGHUP, and they rightly keep ignoring it)."""
    import signal

    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _tune_process(study: Path, out: Path, *extra) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "arvcas.cli", "tune", str(study), "--out", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=default_signals)


def _wait_for(proc: subprocess.Popen, marker: str, timeout: float = 120.0) -> list[str]:
    lines: list[str] = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if marker in line:
            return lines
    proc.kill()
    raise AssertionError(f"never saw {marker!r}: {lines} {proc.stderr.read()}")


# a generation of this study is 8 runs, about 0.1 s on 2 cores: 0.02 s after gen 2 is printed is inside gen 3
@pytest.mark.parametrize("marker,delay", [("Table 2 gains", 0.0), ("gen 2/", 0.02)], ids=["before-gen-1", "mid-gen-3"])
def test_sigkill_then_resume_is_identical(reference, tmp_path, marker, delay):
    study, ref = reference
    out = tmp_path / "out"
    p = _tune_process(study, out)
    _wait_for(p, marker)
    time.sleep(delay)
    p.send_signal(signal.SIGKILL)
    p.wait(timeout=30)
    c = ck.read_checkpoint(out / "front.h5")  # the last complete checkpoint survives the kill
    assert c.status == "running" and c.n_gen < GENS
    (out / f".front.h5{TMP_MARK}99999-x").write_bytes(b"half a file")  # as if killed while writing
    run_study(load_study(study), out, say=quiet, resume=True)
    assert_same_study(ref, ck.read_checkpoint(out / "front.h5"))
    assert not list(out.glob(f".front.h5{TMP_MARK}*")) and not (out / ck.StudyLock.NAME).exists()


def test_sigint_finishes_the_generation_and_prints_how_to_resume(reference, tmp_path):
    study, ref = reference
    out = tmp_path / "out"
    p = _tune_process(study, out)
    _wait_for(p, "gen 1/")
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == 130, stderr
    assert "stopping after this generation" in stderr and "Traceback" not in stderr
    assert f"resume with: arvcas tune {study} --out {out} --resume" in stdout
    c = ck.read_checkpoint(out / "front.h5")
    assert c.status == "interrupted" and 1 <= c.n_gen < GENS
    rc = cli.main(["tune", str(study), "--out", str(out), "--resume"])
    assert rc == 0
    assert_same_study(ref, ck.read_checkpoint(out / "front.h5"))


def test_second_tune_on_the_same_directory_is_refused(reference, tmp_path, capsys):
    study, _ = reference
    out = tmp_path / "out"
    out.mkdir()
    with ck.StudyLock(out):
        rc = cli.main(["tune", str(study), "--out", str(out)])
        err = capsys.readouterr().err
        assert rc == 2 and "another 'arvcas tune'" in err and f"pid {os.getpid()}" in err and err.count("\n") == 1
    assert not (out / "front.h5").exists()


def test_failed_checkpoint_write_keeps_the_previous_one(reference, tmp_path, monkeypatch):
    study, _ = reference
    out = tmp_path / "out"
    run_study(load_study(study), out, say=quiet, stop_after=1)
    before = (out / "front.h5").read_bytes()
    real = ck._write
    calls = {"n": 0}

    def full_disk(*args):
        calls["n"] += 1
        real(*args)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(ck, "_write", full_disk)
    with pytest.raises(ck.CheckpointError, match="No space left on device.*previous one is kept"):
        run_study(load_study(study), out, say=quiet, resume=True)
    assert calls["n"] == 1
    assert (out / "front.h5").read_bytes() == before
    assert ck.read_checkpoint(out / "front.h5").n_gen == 1
    assert not list(out.glob(f".front.h5{TMP_MARK}*")) and not (out / ck.StudyLock.NAME).exists()


def test_foreign_or_truncated_front_files(reference, tmp_path, capsys):
    import h5py

    study, _ = reference
    good = tmp_path / "good"
    run_study(load_study(study), good, say=quiet, stop_after=1)
    data = (good / "front.h5").read_bytes()
    trunc = tmp_path / "trunc"
    trunc.mkdir()
    (trunc / "front.h5").write_bytes(data[: len(data) // 2])
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    with h5py.File(foreign / "front.h5", "w") as f:
        f["x"] = 1
    text = tmp_path / "text"
    text.mkdir()
    (text / "front.h5").write_text("hello")
    for d, msg in [(trunc, "front.h5: "), (foreign, "not an arvcas tuning front"), (text, "not a readable HDF5 file")]:
        for argv in (["tune", str(study), "--out", str(d), "--resume"], ["front", "export", str(d / "front.h5"), "--format", "csv"]):
            rc = cli.main(argv)
            err = capsys.readouterr().err
            assert rc == 2 and msg in err and err.count("\n") == 1 and "Traceback" not in err, (argv, err)


def test_infeasible_candidates_are_constraint_violations(tmp_path):
    s = load_study(write_tiny(tmp_path / "s.toml"))
    task = eval_task(s, "agsta")
    g0 = default_gains("agsta")
    wild = g0 * np.exp(np.random.default_rng(1).uniform(-np.log(10), np.log(10), (3, g0.size)))
    G = np.vstack([g0, wild])
    ev = evaluate_gains(LocalEngine(1), task, G)
    assert ev.ok[0, 0] and not ev.ok[0, 1:].all()
    bad = ~ev.ok[0]
    assert np.isnan(ev.F[bad]).all() and np.isfinite(ev.F[~bad]).all()
    np.testing.assert_array_equal(ev.G[~bad, 0], 0.0)
    np.testing.assert_allclose(ev.G[bad, 0], 1 + (100.0 - ev.t_fail[0, bad]) / 100.0)
    assert (ev.G[bad, 0] > 1).all() and (ev.G[bad, 0] <= 2).all()
    # what pymoo sees: finite placeholder objectives, positive constraint violation
    names, lo, hi, _ = s.bounds("agsta")
    prob = GainProblem(names, np.log10(lo) - 2, np.log10(hi) + 2, lambda g: evaluate_gains(LocalEngine(1), task, g))
    X = np.log10(G)
    out = prob.evaluate(X, return_as_dictionary=True)
    assert (out["F"][bad] == INFEASIBLE_F).all() and (out["G"][bad, 0] > 0).all()
    np.testing.assert_array_equal(out["F"][~bad], prob.last.F[~bad])
    np.testing.assert_array_equal(prob.last.G, ev.G)
