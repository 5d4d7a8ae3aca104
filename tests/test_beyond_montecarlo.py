"""Monte Carlo studies: the draw rule, batch = single runs, files that reproduce bit for bit, the
paired comparison, the CLI. Uses the default scenario at h = 0.1 s (compiled runs shared with the
closed-loop tests) and a handful of runs."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

from arvcas.controllers import gains
from arvcas.sim import scenario
from arvcas.experiments import montecarlo as mc_mod
from arvcas.experiments.montecarlo import compare, compare_markdown, draw, read_montecarlo, reproduce, run_montecarlo, summary, summary_markdown, write_montecarlo
from arvcas.cli import main
from arvcas.io.results import ResultsError
from arvcas.sim.simulation import simulate

RUNS = 6


@pytest.fixture(scope="module")
def mc_proposed():
    return run_montecarlo("proposed", RUNS, seed=11)


def test_draws_within_bounds_prefix_stable_and_seeded():
    d = draw(50, seed=7, spread=0.3)
    assert d.noise_seed.dtype == np.int64 and np.all(d.noise_seed >= 0)
    assert len(set(d.noise_seed.tolist())) == 50
    assert np.all((d.factors >= 0.7) & (d.factors <= 1.3)) and d.factors.shape == (50, 4)
    assert np.all((d.phase >= 0) & (d.phase < 2 * math.pi)) and d.phase.shape == (50, 6)
    # run i depends on (seed, i, spread) only: a shorter study is a prefix of a longer one
    d10 = draw(10, seed=7, spread=0.3)
    assert d10.same_as(type(d)(7, 0.3, d.noise_seed[:10], d.factors[:10], d.phase[:10]))
    assert not draw(10, seed=8).same_as(d10)
    # the factors cover the box (not only a corner): 200 runs, each factor spans most of [0.7, 1.3]
    big = draw(200, seed=0).factors
    assert np.all(big.min(axis=0) < 0.75) and np.all(big.max(axis=0) > 1.25)
    with pytest.raises(ValueError, match="spread"):
        draw(3, spread=1.5)
    with pytest.raises(ValueError, match="runs"):
        draw(0)


def test_each_row_is_its_own_single_run(mc_proposed):
    d = mc_proposed.draws
    cfg = scenario.load_scenario()
    for i in (0, RUNS - 1):
        r = simulate("proposed", seed=int(d.noise_seed[i]), cfg=cfg, uncertainty=d.factors[i], phase=d.phase[i])
        np.testing.assert_allclose(mc_proposed.chat[i], r.chat, rtol=1e-12)
        np.testing.assert_allclose(mc_proposed.rmse[i], r.rmse, rtol=1e-12)
    assert mc_proposed.ok.all() and np.isnan(mc_proposed.t_fail).all()
    # the draws matter: different phases give different RMSE
    assert np.ptp(mc_proposed.rmse[:, 0]) > 0


def test_file_roundtrip_and_reproduction_bit_for_bit(mc_proposed, tmp_path):
    p = write_montecarlo(mc_proposed, tmp_path / "mc.h5")
    back = read_montecarlo(p)
    for k in ("chat", "rmse", "ok", "t_fail", "gains"):
        assert np.array_equal(getattr(back, k), getattr(mc_proposed, k), equal_nan=k != "ok")
    assert back.draws.same_as(mc_proposed.draws) and back.draws.master_seed == 11
    assert back.config_text == mc_proposed.config_text and back.meta["artifact_key"]
    with h5py.File(p) as f:  # the configuration travels with the file
        for k in ("config", "params", "gains", "master_seed", "spread", "draw_rule", "arvcas_version",
                  "casadi_version", "numpy_version", "artifact_key"):
            assert k in f.attrs
    new, diff = reproduce(p)
    assert diff == []
    assert np.array_equal(new.chat, mc_proposed.chat)


def test_summary_intervals(mc_proposed):
    s = summary(mc_proposed)
    for d in gains.DOFS:
        iv = s["chat"][d]["mean"]
        assert iv.n == RUNS and iv.lo < iv.estimate < iv.hi
        p5, p50, p95 = s["chat"][d]["pct"]
        assert p5 <= p50 <= p95
    assert s["n_fail"] == 0 and s["failures"].lo == 0.0 and 0 < s["failures"].hi < 0.5
    md = summary_markdown(mc_proposed)
    assert "95 % t-interval" in md and "Wilson" in md and md.count("\n| ") == 7


def test_paired_comparison_with_agsta(mc_proposed):
    ag = run_montecarlo("agsta", RUNS, seed=11)
    assert ag.draws.same_as(mc_proposed.draws)  # same master seed: the same draws, so paired
    c = compare(mc_proposed, ag)
    assert c["paired"] and c["n"] == RUNS
    for d in gains.DOFS:
        e = c["chat"][d]
        iv = e["diff"]
        assert iv.estimate == pytest.approx(np.mean(mc_proposed.chat[:, gains.DOFS.index(d)]
                                                    - ag.chat[:, gains.DOFS.index(d)]))
        assert e["certain"] == (iv.lo > 0 or iv.hi < 0)
    # a different master seed is not paired: Welch's interval instead
    other = run_montecarlo("agsta", RUNS, seed=12)
    assert not compare(mc_proposed, other)["paired"]
    md = compare_markdown(mc_proposed, ag)
    assert "paired over the 6 shared draws" in md


def test_cli_same_seed_same_file_bit_for_bit(tmp_path, capsys):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    for p in (a, b):
        assert main(["montecarlo", "--controller", "proposed", "--runs", "3", "--seed", "4", "--out", str(p)]) == 0
    assert (tmp_path / "a.md").exists()
    with h5py.File(a) as fa, h5py.File(b) as fb:
        for k in fa:
            assert np.array_equal(fa[k][()], fb[k][()], equal_nan=fa[k].dtype.kind == "f"), k
        for k in fa.attrs:
            if k != "created":
                assert np.array_equal(np.asarray(fa.attrs[k]), np.asarray(fb.attrs[k])), k
    capsys.readouterr()
    assert main(["montecarlo", "--check", str(a)]) == 0
    assert "reproduced bit for bit" in capsys.readouterr().out


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["montecarlo", "--controller", "lqr", "--runs", "2", "--out", str(tmp_path / "x.h5")]) == 2
    assert main(["montecarlo", "--controller", "proposed", "--runs", "2", "--out", str(tmp_path / "no/x.h5")]) == 2
    assert main(["montecarlo", "--controller", "proposed", "--runs", "0", "--out", str(tmp_path / "x.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(e.startswith("arvcas: error: ") for e in err)
    (tmp_path / "not.h5").write_text("hello")
    with pytest.raises(ResultsError, match="not an HDF5 file"):
        read_montecarlo(tmp_path / "not.h5")
    assert not mc_mod.is_montecarlo_file(tmp_path / "not.h5")
