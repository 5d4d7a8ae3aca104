"""MATLAB files of results and fronts, read back with scipy.io.loadmat (an independent reader)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.io import loadmat

import arvcas
from arvcas.io.matfile import MatError, write_front_mat, write_result_mat
from arvcas.tuning.front import read_front

FRONT = Path(__file__).resolve().parents[1] / "results/tuning/paper/proposed/front.h5"


@pytest.fixture(scope="module")
def result():
    return arvcas.simulate("pid", seed=4)


def test_result_round_trip(result, tmp_path):
    p = write_result_mat(result, tmp_path / "run.mat")
    m = loadmat(p, simplify_cells=True)
    assert m["arvcas"]["format"] == "arvcas-result" and m["controller"] == "pid"
    n = len(result.t)
    np.testing.assert_array_equal(m["t"], result.t)
    for sig in result.signals:
        a = np.asarray(m[sig.name], dtype=float)
        np.testing.assert_array_equal(a.reshape(result.series[sig.name].shape), result.series[sig.name])
        assert m["units"][sig.name] == sig.units
    raw = loadmat(p)  # without simplification: MATLAB's shapes
    assert raw["eta"].shape == (n, 6) and raw["t"].shape == (n, 1) and raw["chat"].shape == (1, 6)
    assert raw["gains"].shape == (1, 18) and raw["gain_names"].shape == (1, 18)
    np.testing.assert_array_equal(m["chat"], result.chat)
    assert list(m["gain_names"])[:3] == ["x.kp", "x.ki", "x.kd"]
    assert m["units"]["eta"] == "m, m, m, rad, rad, rad" and np.isnan(m["t_fail"])


@pytest.mark.floor  # scipy.io's .mat writer at scipy's floor, a committed front read with h5py's
def test_front_round_trip(tmp_path):
    fr = read_front(FRONT)
    p = write_front_mat(fr, tmp_path / "front.mat")
    raw = loadmat(p)
    f, n = fr.gains.shape
    assert raw["F"].shape == (f, 2) and raw["gains"].shape == (f, n) and raw["X"].shape == (f, n)
    np.testing.assert_array_equal(raw["F"], fr.F)
    np.testing.assert_array_equal(raw["X"], fr.X)
    np.testing.assert_allclose(10 ** raw["X"], raw["gains"], rtol=1e-13)  # X is log10 of the gains
    k = len(fr.draw_seeds)
    assert raw["chat"].shape[:2] == (f, 6) and (k == 1 or raw["chat"].shape[2] == k)
    m = loadmat(p, simplify_cells=True)
    assert m["arvcas"]["format"] == "arvcas-front" and m["controller"] == "proposed"
    assert 1 <= m["knee"] <= f and m["columns"]["F"].tolist() == ["f_chat", "f_rmse"]
    assert "log10" in m["description"]["X"]


def test_bad_name_is_one_line(result, tmp_path):
    with pytest.raises(MatError) as e:
        write_result_mat(result, tmp_path / "run.txt")
    assert "\n" not in str(e.value) and "run.txt" in str(e.value)
