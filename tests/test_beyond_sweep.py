"""Sampling-period sweep: the zigzag measures on constructed k1 series, and one small sweep (the
traditional law at h = 0.1 s and 0.2 s: one new compile) with its files and CLI."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from arvcas.controllers import gains
from arvcas.experiments.sweep import read_sweep, run_sweep, sweep_markdown, write_sweep_dir, zigzag, zigzag_time_fraction
from arvcas.cli import main

G = gains.default_gains("proposed")
P = gains.unpack("proposed", G)
KMIN, L, SIGMA = (np.asarray(P[k]) for k in ("k1min", "l", "sigma"))


def test_zigzag_counts_on_constructed_series():
    h, n = 0.1, 200
    k1 = np.tile(KMIN, (n + 1, 1))
    s = np.zeros((n + 1, 6))  # |s| <= sigma throughout
    # DOF 0: the traditional pattern, +-l h about k1min from sample 100 on
    k1[100:, 0] = KMIN[0] + L[0] * h * (np.arange(n + 1 - 100) % 2)
    # DOF 1: one genuine excursion: s leaves its band, k1 rises one step, then decays back (proposed law)
    s[50, 1] = 10 * SIGMA[1]
    k1[51, 1] = KMIN[1] + L[1] * h
    k1[52, 1] = KMIN[1] + 0.5 * L[1] * h
    z = zigzag(k1, s, "proposed", G, h)
    assert z["reversals"][0] == n - 101  # every interior sample of the alternating stretch
    assert z["rises_inside"][0] == (n - 100) // 2  # each upward step, although |s| <= sigma
    assert z["amplitude"][0] == pytest.approx(L[0] * h)
    assert z["reversals"][1] == 1 and z["rises_inside"][1] == 0  # the rise was asked for by s
    assert np.all(z["reversals"][2:] == 0) and np.all(z["amplitude"][2:] == 0)
    assert zigzag(k1, s, "agsta", gains.default_gains("agsta"), h) is None  # no k1min: not defined


@pytest.fixture(scope="module")
def small_sweep():
    return run_sweep([0.1, 0.2], controllers=["traditional"], seeds=[0])


def test_traditional_zigzag_grows_with_h(small_sweep, tmp_path):
    sw = small_sweep
    assert sw.ok.all() and sw.chat.shape == (1, 2, 1, 6)
    rev, amp = sw.reversals[0, :, 0], sw.amplitude[0, :, 0]
    assert np.all(rev > 100)  # it zigzags at both periods,
    for j, h in enumerate(sw.hs):  # by exactly one step l h each time,
        np.testing.assert_allclose(amp[j], L * h, rtol=1e-9)
    frac = zigzag_time_fraction(sw)[0, :, 0]
    assert np.all(frac > 0.5)  # for most of the run at either h (measured 0.89 and 0.89)
    assert np.all(sw.rises_inside[0, :, 0] > 0)
    # k1 series of the first seed are kept for the figure: N + 1 samples at each h
    assert [k.shape[0] for k in sw.k1_seed0["traditional"]] == [1001, 501]


def test_sweep_files(small_sweep, tmp_path):
    files = write_sweep_dir(small_sweep, tmp_path / "sw")
    assert {p.name for p in files.values()} == {"sweep.h5", "sweep.md", "sweep.png"}
    back = read_sweep(files["h5"])
    for k in ("chat", "rmse", "ok", "reversals", "rises_inside", "amplitude"):
        assert np.array_equal(getattr(back, k), getattr(small_sweep, k), equal_nan=k != "ok")
    assert back.hs == (0.1, 0.2) and back.seeds == (0,) and back.config_text == small_sweep.config_text
    with h5py.File(files["h5"]) as f:
        for k in ("config", "params", "zigzag_definition", "arvcas_version", "casadi_version", "noise_scale"):
            assert k in f.attrs
        assert np.array_equal(f["gains/traditional"][()], gains.default_gains("traditional"))
    md = sweep_markdown(back)
    assert "| traditional | 0.2 | 1/1 |" in md
    assert main(["sweep", "--check", str(files["h5"])]) == 0  # re-run from the file alone: bit for bit


def test_sweep_cli_bad_input_one_line(tmp_path, capsys):
    assert main(["sweep", "--h", "0.015", "--out", str(tmp_path / "o")]) == 2  # 100 s is not a whole number of samples
    assert main(["sweep", "--h", "0.1", "--controllers", "lqr", "--out", str(tmp_path / "o")]) == 2
    assert main(["sweep", "--h", "0.1,0.1", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(e.startswith("arvcas: error: ") for e in err)
    assert main(["sweep", "--help"]) == 0 and main(["montecarlo", "--help"]) == 0
