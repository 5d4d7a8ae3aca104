"""Every wait is bounded: a Dask cluster that loses all its workers mid-study ends with a one-line
error within the timeout, and the last checkpoint is intact."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from arvcas.tuning import checkpoint as ck
from arvcas.tuning import load_study, run_study
from arvcas.tuning.engines import DaskEngine, EngineError

from test_tuning_study import write_tiny
from trust_helpers import bounded

distributed = pytest.importorskip("distributed")


def test_losing_every_worker_ends_the_study_with_the_checkpoint_kept(tmp_path):
    study = load_study(write_tiny(tmp_path / "tiny.toml", controller="agsta", generations=3))
    out = tmp_path / "out"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        eng = dataclasses.replace(study.engine, name="dask", scheduler=cluster.scheduler_address, timeout_s=3.0)
        saved = {}

        def say(msg):
            if " gen 1/" in msg:  # generation 1 is checkpointed: now every worker goes away
                saved["bytes"] = (out / "front.h5").read_bytes()
                cluster.scale(0)

        e = bounded(lambda: run_study(study.with_engine(eng), out, say=say), timeout=300)
    assert isinstance(e, EngineError), e
    msg = str(e)
    assert "every worker was lost and none came back within 3 s" in msg and "\n" not in msg
    assert "checkpoint of generation 1 is kept" in msg and "resume with: arvcas tune" in msg
    assert (out / "front.h5").read_bytes() == saved["bytes"]
    assert ck.read_checkpoint(out / "front.h5").n_gen == 1
    assert not (out / ck.StudyLock.NAME).exists()


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0, 0.0])
def test_invalid_engine_timeouts_are_refused(bad):
    with pytest.raises(EngineError, match="timeout must be a finite number of seconds > 0"):
        DaskEngine(scheduler="tcp://127.0.0.1:1", timeout_s=bad)


def test_losing_a_worker_and_the_shipped_libraries_keeps_the_study_going(tmp_path):
    """One of two workers is killed and the libraries shipped to the workers are lost after generation 1:
    the generation is evaluated again on the worker that remains (the libraries sent anew), and the
    front is the local engine's, bit for bit."""
    import os
    import signal

    study = load_study(write_tiny(tmp_path / "tiny.toml", controller="agsta", generations=3))
    run_study(study, tmp_path / "local", say=lambda m: None)
    ref = ck.read_checkpoint(tmp_path / "local" / "front.h5")
    out = tmp_path / "out"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        eng = dataclasses.replace(study.engine, name="dask", scheduler=cluster.scheduler_address, timeout_s=30.0)
        engines_made = []
        real = DaskEngine.prepare

        def prepare(self, task):
            engines_made.append(self)
            return real(self, task)

        def say(msg):
            if " gen 1/" in msg:
                victim = sorted(client.scheduler_info()["workers"])[0]
                pid = client.run(os.getpid, workers=[victim])[victim]
                os.kill(pid, signal.SIGKILL)  # the nanny starts a new worker without the libraries
                for e in engines_made[-1:]:
                    e.client.cancel(list(e._bundles.values()))  # and the scattered libraries are gone

        DaskEngine.prepare = prepare
        try:
            e = bounded(lambda: run_study(study.with_engine(eng), out, say=say), timeout=300)
        finally:
            DaskEngine.prepare = real
    assert e is None, e
    got = ck.read_checkpoint(out / "front.h5")
    assert got.n_gen == 3
    for k in ("X", "F", "chat", "rmse"):
        np.testing.assert_array_equal(getattr(got, k), getattr(ref, k), err_msg=k)
