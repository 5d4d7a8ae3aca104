"""Robust fronts and ``compare`` on Monte Carlo files, on a tiny tuning study run here (the proposed
controller, 8 candidates x 2 generations, one draw: about 1 s with the shared compiled run)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from arvcas.controllers import gains
from studytext import tiny_study
from arvcas.experiments.montecarlo import run_montecarlo, write_montecarlo
from arvcas.experiments.robust import front_member, read_robust, robust_front, robust_markdown, write_robust_dir
from arvcas.cli import main

STUDY = tiny_study(controller="proposed", seed=3, population=8, generations=2, scale=3.0, include_table2=True)


@pytest.fixture(scope="module")
def front_file(tmp_path_factory):
    from arvcas.tuning.run import run_study
    from arvcas.tuning.study import load_study

    d = tmp_path_factory.mktemp("tiny")
    (d / "tiny.toml").write_text(STUDY)
    (out,) = run_study(load_study(d / "tiny.toml"), d / "out", say=lambda m: None, study_file=str(d / "tiny.toml"))
    return out.path


@pytest.fixture(scope="module")
def robust(front_file):
    return robust_front(front_file, 5, seed=2)


def test_members_and_table2_on_the_same_draws(front_file, robust):
    from arvcas.tuning.front import read_front

    fr = read_front(front_file)
    rf = robust
    assert rf.size == fr.size and np.array_equal(rf.gains, fr.gains) and np.array_equal(rf.F_front, fr.F)
    assert rf.chat.shape == (fr.size, 5, 6) and rf.table2_chat.shape == (5, 6)
    # each row is a Monte Carlo study of that member on the shared draws
    mc = run_montecarlo("proposed", 5, seed=2, gains=fr.gains[0])
    np.testing.assert_array_equal(rf.chat[0], mc.chat)
    mc2 = run_montecarlo("proposed", 5, seed=2)
    np.testing.assert_array_equal(rf.table2_chat, mc2.chat)
    assert np.array_equal(rf.table2_gains, gains.default_gains("proposed"))


def test_robust_flags(robust):
    st = robust.stats()
    f = robust.size
    M, nd, nf = st["F_mean"][:f], st["robust_nd"], st["n_fail"][:f]
    assert nd.any()
    for i in range(f):  # robust ND = no failed draw and nobody without failures dominates the mean
        dominated = any(np.all(M[k] <= M[i]) and np.any(M[k] < M[i]) for k in range(f) if k != i and nf[k] == 0)
        assert nd[i] == (nf[i] == 0 and not dominated)
    assert not np.any(nd & st["certainly_dominated"])  # certainly dominated members are dominated on the means
    assert np.all(st["F_lo"][np.isfinite(st["F_lo"])] <= st["F_mean"][np.isfinite(st["F_lo"])])


def test_files_and_knee(front_file, robust, tmp_path):
    files = write_robust_dir(robust, tmp_path / "rob")
    assert {p.name for p in files.values()} == {"robust.h5", "robust.md", "robust.png"}
    back = read_robust(files["h5"])
    for k in ("gains", "F_front", "chat", "rmse", "ok", "table2_chat"):
        assert np.array_equal(getattr(back, k), getattr(robust, k), equal_nan=k != "ok")
    assert back.draws.same_as(robust.draws) and back.knee == robust.knee
    with h5py.File(files["h5"]) as f:
        for k in ("config", "params", "master_seed", "runs", "spread", "draw_rule", "front_path", "arvcas_version"):
            assert k in f.attrs
    assert "stay non-dominated" in robust_markdown(back)
    c, g, text, what = front_member(front_file, "knee")
    assert c == "proposed" and np.array_equal(g, robust.gains[robust.knee]) and "knee" in what
    with pytest.raises(ValueError, match="front member"):
        front_member(front_file, 99)


def test_cli_front_robust_and_montecarlo_from_front(front_file, tmp_path, capsys):
    assert main(["front", "robust", str(front_file), "--runs", "3", "--out", str(tmp_path / "r")]) == 0
    assert (tmp_path / "r" / "robust.md").exists()
    out = tmp_path / "knee.h5"
    assert main(["montecarlo", "--from-front", str(front_file), "--index", "knee", "--runs", "3",
                 "--out", str(out)]) == 0
    with h5py.File(out) as f:
        assert "knee" in f.attrs["gains_source"]
    # the tuning package's actions are still there
    capsys.readouterr()
    assert main(["front", "export", str(front_file), "--format", "csv"]) == 0
    assert capsys.readouterr().out.startswith("member,")


def test_cli_compare_dispatches_on_file_type(front_file, tmp_path, capsys):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write_montecarlo(run_montecarlo("proposed", 4, seed=5), a)
    g = gains.default_gains("proposed").copy()
    g[gains.gain_names("proposed").index("x.c")] *= 1.5
    write_montecarlo(run_montecarlo("proposed", 4, seed=5, gains=g), b)
    capsys.readouterr()
    assert main(["compare", str(a), str(b), "--report", str(tmp_path / "c.md"), "--plot", str(tmp_path / "c.png")]) == 0
    text = capsys.readouterr().out
    assert "paired over the 4 shared draws" in text and (tmp_path / "c.md").read_text() in text
    assert (tmp_path / "c.png").stat().st_size > 0
    assert main(["compare", str(front_file), str(front_file)]) == 0  # fronts: the tuning package's compare
    assert main(["compare", str(a), str(front_file)]) == 2  # a mix is refused in one line
    assert "not a Monte Carlo file" in capsys.readouterr().err


def test_compare_two_robust_fronts(robust, tmp_path, capsys):
    a = write_robust_dir(robust, tmp_path / "a")["h5"]
    b = write_robust_dir(robust, tmp_path / "b")["h5"]
    capsys.readouterr()
    assert main(["compare", str(a), str(b), "--report", str(tmp_path / "r.md"), "--plot", str(tmp_path / "r.png")]) == 0
    text = (tmp_path / "r.md").read_text()
    assert "on the same draws" in text and "Coverage: 100 %" in text  # a front covers itself
    assert main(["compare", str(a), str(tmp_path / "r.md")]) == 2
    assert "robust-front file" in capsys.readouterr().err


def test_draws_toml_is_a_valid_study_draw_list(tmp_path, capsys):
    """--draws-toml K: a tuning study that lists these draws optimises the mean over K draws."""
    from arvcas.experiments.montecarlo import draw
    from arvcas.tuning.study import load_study

    assert main(["montecarlo", "--draws-toml", "--runs", "3", "--seed", "9"]) == 0
    block = capsys.readouterr().out
    head, _, _ = STUDY.partition("[[evaluation.draws]]")
    (tmp_path / "k3.toml").write_text(head + block + "[engine]\nname = \"local\"\n")
    study = load_study(tmp_path / "k3.toml")
    d = draw(3, 9)
    assert len(study.draws) == 3
    for i, sd in enumerate(study.draws):
        assert sd.noise_seed == d.noise_seed[i]
        assert np.array_equal(np.array(sd.uncertainty), d.factors[i])  # 17 digits: exact
        np.testing.assert_allclose(np.array(sd.phase), d.phase[i], rtol=1e-15)  # via degrees
