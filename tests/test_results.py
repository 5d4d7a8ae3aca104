"""Result files (arvcas.io.results): round trip, layout attributes, atomic writes, refusals.

All on small synthetic Results (no simulation): a real run's round trip is in test_paper.py.
"""

from __future__ import annotations

import datetime as dt
import os
import stat

import h5py
import numpy as np
import pytest

from arvcas.controllers import gains as gains_mod
from arvcas.io import results
from arvcas.system.params import SCHEMA
from arvcas.io.results import ResultsError, read_result, write_result
from arvcas.sim.simulation import Result

pytestmark = pytest.mark.floor  # the result files through h5py at its floor (CI's floor job, docs/testing.md)

SERIES = ("t", "eta", "nu", "eta_hat", "eta_ref", "tau_cmd", "thrust", "s", "k1", "k2", "f_hat", "f_true", "q",
          "payload")


def synthetic(controller="proposed", n=21, ok=True, t_fail=None, seed=3, optional=True) -> Result:
    rng = np.random.default_rng(seed)
    h = 0.1
    m6 = lambda: rng.normal(size=(n, 6))  # noqa: E731
    return Result(
        controller=controller, gains=gains_mod.default_gains(controller), seed=seed,
        t=np.arange(n) * h, eta=m6(), nu=m6(), eta_hat=m6(), eta_ref=m6(), tau_cmd=m6(), thrust=m6(),
        s=m6(), k1=np.abs(m6()), k2=np.abs(m6()), f_hat=m6(), f_true=m6(), q=m6(),
        payload=np.clip(rng.normal(size=n), 0, 1), chat=np.abs(rng.normal(size=6)), rmse=np.abs(rng.normal(size=6)),
        ok=ok, t_fail=t_fail, config_text="[time]\nduration = { value = 2.0, unit = \"s\", source = \"test\" }\n",
        params_vector=rng.normal(size=len(SCHEMA)) if optional else None,
        uncertainty=np.array([1.4, 0.6, 0.7, 0.6]) if optional else None,
        phase=rng.normal(size=6) if optional else None, h=h, version="9.9.9",
        meta={"artifact_key": "abc123", "note": "ünïcode", "n": 3},
    )


def assert_same(a: Result, b: Result) -> None:
    assert list(a.series) == list(b.series)
    assert [s.name for s in a.signals] == [s.name for s in b.signals] == list(a.series)
    for name in (*Result.FIELDS, *a.series):
        va, vb = getattr(a, name), getattr(b, name)
        if isinstance(va, np.ndarray) or isinstance(vb, np.ndarray):
            assert va is not None and vb is not None, name
            np.testing.assert_array_equal(np.asarray(va), np.asarray(vb), err_msg=name)
            assert np.asarray(va).shape == np.asarray(vb).shape, name
        else:
            assert va == vb, (name, va, vb)
            assert type(va) is type(vb), (name, type(va), type(vb))


def one_line(e: pytest.ExceptionInfo) -> str:
    msg = str(e.value)
    assert "\n" not in msg and msg
    return msg


# ---------------------------------------------------------------------------------------------
# round trip and layout


@pytest.mark.parametrize("controller", ["proposed", "agsta", "traditional", "implicit"])
def test_round_trip_every_field(tmp_path, controller):
    r = synthetic(controller)
    p = write_result(r, tmp_path / "run.h5")
    assert p == tmp_path / "run.h5"
    assert_same(r, read_result(p))


def test_round_trip_without_optional_fields(tmp_path):
    r = synthetic(optional=False)
    back = read_result(write_result(r, tmp_path / "run.h5"))
    assert back.params_vector is None and back.uncertainty is None and back.phase is None
    assert_same(r, back)


def test_diverged_run_says_so(tmp_path):
    r = synthetic(ok=False, t_fail=1.3)
    p = write_result(r, tmp_path / "bad.h5")
    with h5py.File(p, "r") as f:
        assert not f.attrs["ok"]
        assert f.attrs["t_fail"] == 1.3
        assert "diverged at t = 1.3 s" in f.attrs["status"]
    back = read_result(p)
    assert back.ok is False and back.t_fail == 1.3 and back.diverged
    assert_same(r, back)


def test_layout_attributes(tmp_path):
    r = synthetic("agsta")
    p = write_result(r, tmp_path / "run.h5")
    with h5py.File(p, "r") as f:
        a = f.attrs
        assert a["format"] == "arvcas-result" and a["format_version"] == results.FORMAT_VERSION
        for k in ("controller", "chat", "rmse", "seed", "gains", "gain_names", "config", "params", "param_names",
                  "uncertainty", "phase", "h", "ok", "t_fail", "status", "arvcas_version", "casadi_version",
                  "created"):
            assert k in a, k
        assert np.isnan(a["t_fail"]) and a["status"].startswith("completed")
        assert list(a["gain_names"]) == gains_mod.gain_names("agsta")
        assert list(a["param_names"]) == list(SCHEMA)
        assert dt.datetime.fromisoformat(a["created"]).tzinfo is not None
        assert set(f.keys()) == set(SERIES)
        for name in SERIES:
            ds = f[name]
            assert ds.attrs["units"] and ds.attrs["description"], name
            assert ds.shape[0] == len(r.t)
        assert f["eta"].attrs["frame"] == "{n}" and f["nu"].attrs["frame"] == "{b}"
        assert f["tau_cmd"].attrs["frame"] == "{b}" and f["f_hat"].attrs["frame"] == "{n}"
        assert f["eta"].attrs["units"] == "m, m, m, rad, rad, rad"
        assert f["thrust"].attrs["units"] == "N"


def test_overwrites_existing_file(tmp_path):
    p = tmp_path / "run.h5"
    write_result(synthetic(seed=1), p)
    r2 = synthetic(seed=2)
    write_result(r2, p)
    assert_same(r2, read_result(p))
    assert sorted(os.listdir(tmp_path)) == ["run.h5"]


def test_bad_result_refused(tmp_path):
    r = synthetic()
    r.eta = r.eta[:, :5]
    with pytest.raises(ResultsError) as e:
        write_result(r, tmp_path / "run.h5")
    assert "Result.eta" in one_line(e)
    assert not os.listdir(tmp_path)


# ---------------------------------------------------------------------------------------------
# atomic writing


@pytest.mark.parametrize("exc", [RuntimeError("disk on fire"), KeyboardInterrupt()])
def test_interrupted_write_leaves_no_file(tmp_path, monkeypatch, exc):
    calls = []
    real_put = results._put

    def put(f, name, data, *sig):
        calls.append(name)
        if len(calls) == 4:  # midway through the datasets
            raise exc
        real_put(f, name, data, *sig)

    monkeypatch.setattr(results, "_put", put)
    with pytest.raises(type(exc)):
        write_result(synthetic(), tmp_path / "run.h5")
    assert len(calls) == 4
    assert os.listdir(tmp_path) == []  # neither the final name nor a temporary file


def test_interrupted_write_keeps_previous_file(tmp_path, monkeypatch):
    p = tmp_path / "run.h5"
    write_result(synthetic(seed=1), p)
    before = p.read_bytes()

    def put(f, name, data, *sig):
        raise RuntimeError("interrupted")

    monkeypatch.setattr(results, "_put", put)
    with pytest.raises(RuntimeError):
        write_result(synthetic(seed=2), p)
    assert p.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["run.h5"]
    assert_same(synthetic(seed=1), read_result(p))


def test_full_disk_is_one_line_and_keeps_previous_file(tmp_path, monkeypatch):
    """ENOSPC midway: a one-line ResultsError naming the file, the previous result intact, no temp file."""
    p = tmp_path / "run.h5"
    write_result(synthetic(seed=1), p)
    before = p.read_bytes()

    def put(f, name, data, *sig):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(results, "_put", put)
    with pytest.raises(ResultsError, match="No space left on device") as ei:
        write_result(synthetic(seed=2), p)
    assert str(p) in one_line(ei)
    assert p.read_bytes() == before and sorted(os.listdir(tmp_path)) == ["run.h5"]


def test_missing_directory_refused_before_work(tmp_path):
    target = tmp_path / "nope" / "run.h5"
    # a non-Result would fail validation: the directory error must come first
    with pytest.raises(ResultsError) as e:
        write_result(None, target)
    msg = one_line(e)
    assert str(target) in msg and "does not exist" in msg


def test_directory_is_a_file_refused(tmp_path):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ResultsError) as e:
        write_result(synthetic(), tmp_path / "afile" / "run.h5")
    assert "not a directory" in one_line(e)


def test_read_only_directory_refused(tmp_path):
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o555)
    try:
        with pytest.raises(ResultsError) as e:
            write_result(None, d / "run.h5")
        msg = one_line(e)
        assert str(d / "run.h5") in msg and "not writable" in msg
        assert os.listdir(d) == []
    finally:
        d.chmod(stat.S_IRWXU)


def test_target_is_directory_refused(tmp_path):
    (tmp_path / "run.h5").mkdir()
    with pytest.raises(ResultsError) as e:
        write_result(synthetic(), tmp_path / "run.h5")
    assert "is a directory" in one_line(e)


# ---------------------------------------------------------------------------------------------
# reading refusals


def test_missing_file_refused(tmp_path):
    with pytest.raises(ResultsError) as e:
        read_result(tmp_path / "none.h5")
    assert "no such file" in one_line(e)


def test_not_hdf5_refused(tmp_path):
    p = tmp_path / "x.h5"
    p.write_text("hello, not HDF5\n")
    with pytest.raises(ResultsError) as e:
        read_result(p)
    msg = one_line(e)
    assert str(p) in msg and "not an HDF5 file" in msg


def test_foreign_hdf5_refused(tmp_path):
    p = tmp_path / "foreign.h5"
    with h5py.File(p, "w") as f:
        f.create_dataset("t", data=np.arange(3.0))
    with pytest.raises(ResultsError) as e:
        read_result(p)
    msg = one_line(e)
    assert str(p) in msg and "not an arvcas result file" in msg and "no 'format'" in msg
    with h5py.File(p, "a") as f:
        f.attrs["format"] = "someone-else"
    with pytest.raises(ResultsError) as e:
        read_result(p)
    assert "someone-else" in one_line(e)


def test_newer_format_version_refused(tmp_path):
    p = write_result(synthetic(), tmp_path / "run.h5")
    with h5py.File(p, "a") as f:
        f.attrs["format_version"] = results.FORMAT_VERSION + 1
    with pytest.raises(ResultsError) as e:
        read_result(p)
    assert "format_version" in one_line(e)


@pytest.mark.parametrize("keep", [0.3, 0.6, 0.95])
def test_truncated_file_refused(tmp_path, keep):
    p = write_result(synthetic(n=200), tmp_path / "run.h5")
    data = p.read_bytes()
    p.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(ResultsError) as e:
        read_result(p)
    msg = one_line(e)
    assert str(p) in msg and ("truncated" in msg or "damaged" in msg)


def test_missing_dataset_refused(tmp_path):
    p = write_result(synthetic(), tmp_path / "run.h5")
    with h5py.File(p, "a") as f:
        del f["f_hat"]
    with pytest.raises(ResultsError) as e:
        read_result(p)
    assert "f_hat" in one_line(e)
