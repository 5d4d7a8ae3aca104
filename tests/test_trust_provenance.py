"""Provenance on resume and replay: a front records the digest of its compiled run and the parameter
vector; resume, replay, front robust, montecarlo --from-front and compare refuse a mismatch (or a file of
an older arvcas that records only its source's hash) unless --allow-model-change, and then the output
records it."""

from __future__ import annotations

import json

import h5py
import numpy as np

from arvcas.io.results import read_result
from arvcas.system.params import load
from arvcas.tuning import checkpoint as ck
from arvcas.tuning import load_study, run_study

from test_tuning_study import write_tiny
from trust_helpers import assert_refused, run, run3, synthetic_front

OLD = "0" * 64


def test_replays_refuse_another_model(tmp_path, capsys):
    d = tmp_path
    (d / "a").mkdir()
    (d / "b").mkdir()
    (d / "c").mkdir()
    (d / "o").mkdir()
    other_model = synthetic_front(d / "a" / "front.h5", run_digest=OLD)
    old_source = synthetic_front(d / "o" / "front.h5", model_hash=OLD)
    other_params = synthetic_front(d / "b" / "front.h5", params=load().vector() * 1.01)
    good = synthetic_front(d / "c" / "front.h5")
    cases = [
        (["simulate", "--from-front", other_model, "--index", "0"],
         "the compiled run changed (run digest 000000000000"),
        (["simulate", "--from-front", old_source, "--index", "0"],
         "records only the hash of the source that wrote it (model hash 000000000000, "),
        (["simulate", "--from-front", old_source, "--index", "0"], f"re-stamp it: arvcas front restamp {old_source}"),
        (["simulate", "--from-front", other_params, "--index", "0"], "other parameter values than the packaged file"),
        (["montecarlo", "--from-front", other_model, "--index", "knee", "--runs", "2", "--out", d / "m.h5"],
         "the compiled run changed"),
        (["front", "robust", other_model, "--runs", "2"], "front robust"),
        (["front", "robust", other_params, "--runs", "2"], "other parameter values"),
        (["compare", good, old_source], "were computed with different models (model hash"),
        (["compare", good, other_params], "different parameter vectors"),
    ]
    for argv, msg in cases:
        err = assert_refused(argv, capsys, d, msg)
        assert "--allow-model-change" in err


def test_a_front_of_another_casadi_release_says_so(tmp_path, capsys):
    """A run digest that differs where the front records another CasADi release: the refusal names both
    releases (CasADi's generated C differs between them), not a change of arvcas's model."""
    import casadi

    front = synthetic_front(tmp_path / "front.h5", run_digest=OLD)
    with h5py.File(front, "r+") as f:
        v = json.loads(f.attrs["versions"])
        f.attrs["versions"] = json.dumps(v | {"casadi": "3.7.0"}, sort_keys=True)
    err = assert_refused(["simulate", "--from-front", front, "--index", "0"], capsys, tmp_path,
                         f"CasADi 3.7.0 computed it, {casadi.__version__} is installed")
    assert "model code" not in err
    (tmp_path / "same").mkdir()
    same = synthetic_front(tmp_path / "same" / "front.h5", run_digest=OLD)  # the same release: the model changed
    assert_refused(["simulate", "--from-front", same, "--index", "0"], capsys, tmp_path / "same",
                   "the model code or data differ")


def test_allowed_model_change_is_recorded(tmp_path, capsys):
    front = synthetic_front(tmp_path / "front.h5", model_hash=OLD)
    out = tmp_path / "r.h5"
    rc, text, err = run3(["simulate", "--from-front", front, "--index", "1", "--allow-model-change", "--out", out],
                         capsys)
    assert rc in (0, 1), err
    assert "records only the hash of the source" in read_result(out).meta["model_change_allowed"]
    assert "note: replayed under another model" in text
    (tmp_path / "g").mkdir()
    good = synthetic_front(tmp_path / "g" / "front.h5")
    rc, text, err = run3(["compare", good, front, "--allow-model-change"], capsys)
    assert rc == 0, err
    assert "note: the two fronts were computed with different models (model hash" in text


def test_resume_refuses_another_model_and_records_an_allowed_one(tmp_path, capsys):
    study = write_tiny(tmp_path / "s.toml")
    out = tmp_path / "out"
    run_study(load_study(study), out, say=lambda m: None, stop_after=1)
    path = out / "front.h5"
    c = ck.read_checkpoint(path)
    assert len(c.model_hash) == 64 and len(c.run_digest) == 64 and np.array_equal(c.params, load().vector())
    with h5py.File(path, "r+") as f:  # as if computed by another model
        f.attrs["run_digest"] = OLD
    err = assert_refused(["tune", study, "--out", out, "--resume"], capsys, tmp_path, "the compiled run changed")
    assert "continuing would mix two models" in err
    rc, err = run(["tune", study, "--out", out, "--resume", "--allow-model-change"], capsys)
    assert rc == 0, err
    c = ck.read_checkpoint(path)
    assert c.run_digest == ck.run_digest(c, load()) and c.n_gen > 1
    assert len(c.model_changes) == 1 and "resumed at generation 1" in c.model_changes[0]
    with h5py.File(path, "r") as f:
        assert json.loads(f.attrs["model_changes"]) == c.model_changes
