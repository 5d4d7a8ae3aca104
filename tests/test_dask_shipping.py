"""Dask workers need neither a C compiler nor a warm cache: the client ships the compiled libraries.

A real ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1, the workers with an empty
compile cache and no ``cc`` on their PATH: a tiny study gives the local engine's front bit for bit.
A worker that cannot take the libraries (another platform, other model code) refuses with a one-line
error naming the worker; an error raised on a worker says it came from one.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from arvcas.build import codegen, shipping
from arvcas.tuning import checkpoint as ck
from arvcas.tuning import engines, load_study, run_study

from test_tuning_study import write_tiny

distributed = pytest.importorskip("distributed")


def _dask_bin() -> str:
    exe = Path(sys.executable).parent / "dask"
    if not exe.exists():
        pytest.skip("the dask command line is not installed beside this Python")
    return str(exe)


@pytest.fixture
def cluster(tmp_path):
    """(scheduler address, worker env): a scheduler and two workers without cc and with an empty cache."""
    dask = _dask_bin()
    sfile = tmp_path / "scheduler.json"
    bindir = tmp_path / "bin"  # only python and dask: no cc, no gcc
    bindir.mkdir()
    for name in ("python", "python3", "dask"):
        src = Path(sys.executable).parent / name
        if src.exists():
            (bindir / name).symlink_to(src)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("DASK_", "ARVCAS_"))}
    # another default level and instruction set than the client's (tests: -O0, -mavx where the CPU has it): a
    # worker uses the libraries it was shipped, as the client built them
    other = "-O3" if codegen.default_opt_level() != "-O3" else "-O1"
    wenv = dict(env, PATH=str(bindir), ARVCAS_CACHE=str(tmp_path / "worker-cache"), OMP_NUM_THREADS="1",
                ARVCAS_OPT_LEVEL=other, ARVCAS_ISA="baseline")
    assert shutil.which("cc", path=wenv["PATH"]) is None
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sfile)], env=env, cwd=tmp_path,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while not sfile.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(sfile.read_text())["address"]
        for i in range(2):
            procs.append(subprocess.Popen([dask, "worker", address, "--nthreads", "1", "--nworkers", "1",
                                           "--no-dashboard", "--name", f"nocc-{i}", "--local-directory",
                                           str(tmp_path / f"w{i}")], env=wenv, cwd=tmp_path,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        yield address, wenv
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def test_workers_without_a_compiler_give_the_local_front(tmp_path, cluster):
    address, wenv = cluster
    study = load_study(write_tiny(tmp_path / "tiny.toml", controller="pid", generations=2))
    run_study(study, tmp_path / "local", say=lambda m: None)
    ref = ck.read_checkpoint(tmp_path / "local" / "front.h5")
    eng = dataclasses.replace(study.engine, name="dask", scheduler=address, timeout_s=60.0)
    log: list[str] = []
    run_study(study.with_engine(eng), tmp_path / "dask", say=log.append)
    got = ck.read_checkpoint(tmp_path / "dask" / "front.h5")
    for k in ("X", "F", "G", "chat", "rmse", "ok", "t_fail"):
        np.testing.assert_array_equal(getattr(got, k), getattr(ref, k), err_msg=k)
    assert got.artifact_key == ref.artifact_key
    assert not any(Path(wenv["ARVCAS_CACHE"]).glob("*.so")), "workers compiled nothing into their cache"


def test_a_worker_refuses_libraries_of_another_platform(tmp_path, cluster):
    address, _ = cluster
    from arvcas.sim.simulation import compiled_run

    run = compiled_run("pid")
    bundle = engines.ship_bundle(run)
    alien = dict(bundle, platform={**bundle["platform"], "machine": "riscv128"})
    client = distributed.Client(address, timeout="30s")
    try:
        fut = client.submit(shipping.preload, alien, pure=False)
        with pytest.raises(Exception) as e:
            fut.result(timeout=60)
        msg = str(e.value)
        assert "\n" not in msg and "riscv128" in msg and "worker" in msg
    finally:
        client.close()


def test_a_bundle_needing_an_instruction_set_the_cpu_lacks_is_refused(monkeypatch):
    """A bundle records the ISA flags its libraries were built with; a process whose CPU lacks one
    refuses it (one line naming the flag and ARVCAS_ISA=baseline), one that has them all loads it."""
    from arvcas.sim.simulation import compiled_run

    bundle = engines.ship_bundle(compiled_run("pid"))
    assert bundle["platform"]["isa"] == list(codegen.isa_flags())
    needs = dict(bundle, platform={**bundle["platform"], "isa": ["-mavx"]})
    monkeypatch.setattr(codegen, "supported_isa", lambda: ())
    with pytest.raises(codegen.CacheError, match="need -mavx, which this CPU lacks.*ARVCAS_ISA=baseline") as e:
        shipping.preload(needs)
    assert "\n" not in str(e.value)
    monkeypatch.setattr(codegen, "supported_isa", lambda: ("-mavx",))
    assert shipping.preload(dict(bundle, platform={**bundle["platform"], "isa": []})) >= 0  # baseline runs anywhere
