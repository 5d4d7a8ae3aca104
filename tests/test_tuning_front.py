"""Fronts as data: export round trip, plot, knee, exact replay of a member, comparison of two fronts."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from arvcas import cli
from arvcas.metrics import normalised_objectives
from arvcas.sim.simulation import simulate, simulate_batch
from arvcas.tuning import compare_fronts, export_front, knee_index, member_gains, read_front, replay, run_study
from arvcas.tuning import load_study

from test_tuning_study import write_tiny


@pytest.fixture(scope="module")
def fronts(tmp_path_factory):
    """Two small finished studies: agsta and proposed (population 8, 3 generations)."""
    d = tmp_path_factory.mktemp("tuning_fronts")
    out = {}
    for c in ("agsta", "proposed"):
        study = write_tiny(d / f"{c}.toml", controller=c)
        run_study(load_study(study), d / c, say=lambda m: None)
        out[c] = d / c / "front.h5"
    return out


def test_front_object(fronts):
    fr = read_front(fronts["agsta"].parent)  # a directory works too
    assert fr.controller == "agsta" and fr.size >= 1 and fr.gains.shape == (fr.size, 48)
    assert np.all(np.diff(fr.F[:, 0]) > 0) and np.all(np.diff(fr.F[:, 1]) < 0)  # sorted, non-dominated
    assert fr.hv > 0 and 0 <= fr.knee() < fr.size
    np.testing.assert_array_equal(fr.F, fr.population_F[fr.index])


def test_export_round_trip(fronts, tmp_path, capsys):
    fr = read_front(fronts["proposed"])
    text = export_front(fronts["proposed"], "csv")
    rows = list(csv.DictReader(io.StringIO(text)))
    assert len(rows) == fr.size
    for i, r in enumerate(rows):
        assert int(r["member"]) == i and int(r["population_row"]) == fr.index[i]
        assert float(r["f_chat"]) == fr.F[i, 0] and float(r["f_rmse"]) == fr.F[i, 1]
        np.testing.assert_array_equal([float(r[n]) for n in fr.names], fr.gains[i])
    assert sum(r["knee"] == "True" for r in rows) == 1
    doc = json.loads(export_front(fronts["proposed"], "json"))
    assert doc["controller"] == "proposed" and doc["gain_names"] == fr.names and doc["seed"] == fr.seed
    for i, m in enumerate(doc["members"]):
        assert [m["f_chat"], m["f_rmse"]] == fr.F[i].tolist()
        assert [m["gains"][n] for n in fr.names] == fr.gains[i].tolist()
    assert doc["hypervolume"] == fr.hv and doc["draws"][0]["noise_seed"] == 0
    # through the CLI, to a file and to stdout
    out = tmp_path / "f.json"
    assert cli.main(["front", "export", str(fronts["proposed"]), "--format", "json", "--out", str(out)]) == 0
    assert json.loads(out.read_text()) == doc
    capsys.readouterr()
    assert cli.main(["front", "export", str(fronts["proposed"]), "--format", "csv"]) == 0
    assert capsys.readouterr().out == text


def test_plot(fronts, tmp_path, capsys):
    png = tmp_path / "front.png"
    assert cli.main(["front", "plot", str(fronts["agsta"]), "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "knee: member" in capsys.readouterr().out
    labels = [t.get_text() for t in read_front(fronts["agsta"]).plot().legends[0].get_texts()]  # below the axes
    assert any("Table 2" in t for t in labels) and any("knee" in t for t in labels)


def test_knee_of_a_simple_front():
    # two straight pieces meeting at (0.2, 0.2), on the diagonal of the normalised front: the corner
    a, b = np.linspace(0, 0.2, 11), np.linspace(0.2, 1, 11)[1:]
    F = np.vstack([np.c_[a, 1 - 4 * a], np.c_[b, 0.2 - 0.25 * (b - 0.2)]])
    assert knee_index(F) == 10
    # the member closest to equal pseudo-weights
    assert knee_index(np.array([[0.0, 1.0], [0.1, 0.3], [0.2, 0.2], [1.0, 0.0]])) == 2
    assert knee_index(F[:1]) == 0


@pytest.mark.parametrize("controller", ["agsta", "proposed"])
def test_member_replays_exactly(fronts, controller):
    """simulate (trace function) and simulate_batch (metrics-only function) reproduce the stored numbers."""
    fr = read_front(fronts[controller])
    i = fr.knee()
    c, g, seed, cfg_text = member_gains(fronts[controller], i)
    assert c == controller and seed == 0
    r = simulate(c, g, seed=seed)
    np.testing.assert_array_equal(r.chat, fr.chat[0, i])
    np.testing.assert_array_equal(r.rmse, fr.rmse[0, i])
    assert normalised_objectives(r.chat, r.rmse) == tuple(fr.F[i])
    ch, rm = simulate_batch(c, g[None, :], seed=seed)
    np.testing.assert_array_equal(ch[0], r.chat)
    ev = replay(fronts[controller], i)
    np.testing.assert_array_equal(ev.F[0], fr.F[i])


def test_simulate_from_front_cli(fronts, capsys):
    fr = read_front(fronts["agsta"])
    rc = cli.main(["simulate", "--from-front", str(fronts["agsta"]), "--index", "0"])
    out = capsys.readouterr().out
    assert rc == 0 and "agsta" in out
    assert f"{fr.chat[0, 0, 0]:12.5g}" in out
    rc = cli.main(["simulate", "--from-front", str(fronts["agsta"]), "--index", str(fr.size)])
    err = capsys.readouterr().err
    assert rc == 2 and f"has {fr.size} front member(s)" in err


def test_compare(fronts, tmp_path, capsys):
    c = compare_fronts(fronts["agsta"], fronts["proposed"])
    fa, fb = read_front(fronts["agsta"]), read_front(fronts["proposed"])
    np.testing.assert_array_equal(c.reference_point, np.maximum(fa.reference_point, fb.reference_point))
    assert c.hv == (fa.hv, fb.hv) and c.labels == ("agsta", "proposed")
    assert 0 <= c.coverage[0] <= 1 and 0 <= c.coverage[1] <= 1
    assert c.regions[0][0] == min(fa.F[0, 0], fb.F[0, 0])
    # a front compared with itself: equal everywhere
    same = compare_fronts(fa, fa, ref=[400.0, 5.0])
    assert same.hv[0] == same.hv[1] and same.coverage == (1.0, 1.0)
    assert {w for _, _, w in same.regions} == {"tie"}
    png = tmp_path / "cmp.png"
    rc = cli.main(["compare", str(fronts["agsta"].parent), str(fronts["proposed"].parent), "--plot", str(png)])
    out = capsys.readouterr().out
    assert rc == 0 and "hypervolume" in out and "where" in out and png.exists()
    rc = cli.main(["compare", str(fronts["agsta"]), str(fronts["proposed"]), "--ref", "1,x"])
    assert rc == 2 and "--ref" in capsys.readouterr().err


def _front_indices_by_pairs(F, G):
    """The definition, pair by pair: feasible rows no other feasible row dominates (ties: the earliest)."""
    feas = [i for i in range(len(F)) if G[i, 0] <= 0 and np.isfinite(F[i]).all()]
    keep = [i for i in feas if not any(j != i and np.all(F[j] <= F[i]) and (np.any(F[j] < F[i]) or j < i)
                                         for j in feas)]
    keep = np.array(keep, dtype=int)
    return keep[np.lexsort((F[keep, 1], F[keep, 0]))] if keep.size else keep


def test_front_indices_is_the_pairwise_definition():
    from arvcas.tuning.checkpoint import front_indices

    rng = np.random.default_rng(7)
    for n in (1, 2, 5, 40, 200):
        F = np.round(rng.uniform(0, 3, (n, 2)), 1)  # coarse values: ties and exact duplicates occur
        F[rng.uniform(size=n) < 0.05] = np.nan
        G = np.where(rng.uniform(size=(n, 1)) < 0.1, 1.0, 0.0)
        got, ref = front_indices(F, G), _front_indices_by_pairs(F, G)
        assert got.dtype == ref.dtype and np.array_equal(got, ref), (n, got, ref)
    assert len(front_indices(np.zeros((3, 2)), np.zeros((3, 1)))) == 1  # three duplicates: the first kept


def test_figures_in_the_format_asked_for(fronts, tmp_path, capsys):
    """front plot and compare --plot write PNG, PDF or SVG by the name's suffix or --format; a format
    arvcas cannot write, or a suffix that contradicts --format, is refused in one line before any work."""
    from arvcas.io import cliargs, style

    assert cliargs.FIGURE_FORMATS == style.FORMATS  # --format's choices are the formats the style writes
    magic = {"png": b"\x89PNG\r\n\x1a\n", "pdf": b"%PDF-", "svg": b"<?xml"}
    for fmt, head in magic.items():
        out = tmp_path / f"front.{fmt}"
        assert cli.main(["front", "plot", str(fronts["agsta"]), "--out", str(out)]) == 0
        assert out.read_bytes().startswith(head), fmt
    assert b"<svg" in (tmp_path / "front.svg").read_bytes()[:2000]
    out = tmp_path / "noext"
    assert cli.main(["front", "plot", str(fronts["agsta"]), "--out", str(out), "--format", "pdf"]) == 0
    assert out.read_bytes().startswith(magic["pdf"])
    assert cli.main(["front", "plot", str(fronts["agsta"].parent), "--format", "svg"]) == 0  # default: next to it
    assert (fronts["agsta"].parent / "front.svg").read_bytes().startswith(magic["svg"])
    capsys.readouterr()
    for argv, msg in ((["--out", str(tmp_path / "f.jpg")], "cannot write .jpg figures"),
                      (["--out", str(tmp_path / "f.png"), "--format", "pdf"], "ends in .png but --format is pdf"),
                      (["--out", str(tmp_path / "f")], "no suffix")):
        assert cli.main(["front", "plot", str(fronts["agsta"]), *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("arvcas: error: ") and msg in err and err.count("\n") == 1, err
    assert not (tmp_path / "f.jpg").exists() and not (tmp_path / "f.png").exists()
    assert cli.main(["compare", str(fronts["agsta"]), str(fronts["proposed"]), "--format", "pdf"]) == 2
    assert "--format: only with --plot" in capsys.readouterr().err
    cmp = tmp_path / "cmp.pdf"
    assert cli.main(["compare", str(fronts["agsta"]), str(fronts["proposed"]), "--plot", str(cmp)]) == 0
    assert cmp.read_bytes().startswith(magic["pdf"])
    # the same figure twice gives the same bytes (no creation date; seeded SVG ids)
    again = tmp_path / "again.svg"
    assert cli.main(["front", "plot", str(fronts["agsta"]), "--out", str(again)]) == 0
    assert again.read_bytes() == (tmp_path / "front.svg").read_bytes()


def test_compare_takes_any_number_of_fronts(fronts, capsys):
    a, b = fronts["agsta"], fronts["proposed"]
    c = compare_fronts(a, b, a)
    fa = read_front(a)
    assert c.labels == ("agsta (agsta) [A]", "proposed", "agsta (agsta) [C]")
    assert c.hv[0] == c.hv[2] and c.coverage_matrix[0][2] == c.coverage_matrix[2][0] == 1.0
    assert all(c.coverage_matrix[i][i] == 1.0 for i in range(3))
    assert {w for _, _, w in c.regions} <= {"A", "B", "C", "tie", "A only", "B only", "C only", "none"}
    assert c.regions[0][0] == min(fa.F[0, 0], read_front(b).F[0, 0])
    two = compare_fronts(a, b)
    assert two.coverage == (two.coverage_matrix[0][1], two.coverage_matrix[1][0])
    assert cli.main(["compare", str(a), str(b), str(a.parent)]) == 0
    out = capsys.readouterr().out
    assert "largest hypervolume" in out and "coverage: share of each column's front" in out
    assert sum(line.startswith(("agsta", "proposed")) for line in out.splitlines()) >= 3
    assert "Table 2 (f_chat, f_rmse)" in out  # Haidou-1's fronts name the paper's table
    assert cli.main(["compare", str(a)]) == 2
    assert "needs two or more fronts" in capsys.readouterr().err


def test_knees_of_a_one_controller_study_directory(fronts, tmp_path, capsys):
    study = fronts["agsta"].parent  # the --out of a study of one controller: DIR/front.h5
    out = tmp_path / "knees"
    assert cli.main(["knees", str(study), "--out", str(out), "--format", "pdf"]) == 0
    names = {p.name for p in out.iterdir() if not p.name.startswith(".")}
    assert names == {"knee_agsta.h5", "knees.md", "knees_states.pdf", "knees_errors.pdf", "knees_thrust.pdf"}
    assert all((out / n).read_bytes().startswith(b"%PDF-") for n in names if n.endswith(".pdf"))
    assert "| agsta |" in (out / "knees.md").read_text()
