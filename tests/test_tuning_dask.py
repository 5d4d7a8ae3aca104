"""The Dask engine gives the local engine's front bit for bit (local cluster over loopback)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from arvcas.tuning import load_study, run_study
from arvcas.tuning import checkpoint as ck

from test_tuning_study import write_tiny

distributed = pytest.importorskip("distributed")


def test_dask_engine_matches_local_engine(tmp_path):
    study = load_study(write_tiny(tmp_path / "tiny.toml", controller="proposed", generations=3))
    run_study(study, tmp_path / "local", say=lambda m: None)
    ref = ck.read_checkpoint(tmp_path / "local" / "front.h5")

    # 1) a scheduler given by address: 2 single-threaded worker processes on 127.0.0.1
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        eng = dataclasses.replace(study.engine, name="dask", scheduler=cluster.scheduler_address, timeout_s=30.0)
        log: list[str] = []
        r = run_study(study.with_engine(eng), tmp_path / "dask", say=log.append, stop_after=2)
        assert r[0].status == "interrupted"
        assert any("dask (tcp://127.0.0.1:" in m and "2 worker(s), 2 thread(s)" in m for m in log), log
    # 2) resumed on a local cluster the engine starts itself (2 workers x 1 thread)
    eng = dataclasses.replace(study.engine, name="dask", scheduler=None, workers=2, timeout_s=30.0)
    run_study(study.with_engine(eng), tmp_path / "dask", say=lambda m: None, resume=True)
    got = ck.read_checkpoint(tmp_path / "dask" / "front.h5")
    for k in ("X", "F", "G", "rank", "crowding", "chat", "rmse", "ok", "t_fail"):
        np.testing.assert_array_equal(getattr(got, k), getattr(ref, k), err_msg=k)
    assert got.rng_state == ref.rng_state and got.artifact_key == ref.artifact_key
    np.testing.assert_array_equal(got.history["hv"], ref.history["hv"])
