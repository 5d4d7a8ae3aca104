"""Tuning any law on its own: the objectives' normalisation never needs the AGSTA to run. On a system whose
AGSTA diverges at its default gains, a PID study runs to the end normalised by the PID's own defaults (and
says so, in its output and its front); a study may give the values itself or name the law; a study with no
law whose defaults run is one line before any generation."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import arvcas
from arvcas import cli
from arvcas.tuning import checkpoint as ck
from arvcas.tuning import load_study

from studytext import short_scenario, small_study

DATA = Path(arvcas.__file__).parent / "data"
SYSTEM = "bluerov2_heavy_alpha5"


@pytest.fixture(scope="module")
def system(tmp_path_factory):
    """The BlueROV2 with AGSTA defaults that diverge (c = k1_0 = 1000 in every DOF: out at 1.5 s)."""
    d = tmp_path_factory.mktemp("sys")
    for f in (f"{SYSTEM}.toml", f"{SYSTEM}.scenario.toml", f"{SYSTEM}.gains.toml", "t200_16v.csv"):
        shutil.copy(DATA / f, d / f)
    g = (d / f"{SYSTEM}.gains.toml").read_text()
    g, n = re.subn(r"(\[agsta\]\ncolumns = .*\n)((?:\w+ = \[.*\]\n)+)", lambda m: m.group(1) + "".join(
        f"{dof} = [1000.0, 0.0021, 0.069, 0.3192, 3.162, 1.2692, 1000.0, 0.002]\n"
        for dof in ("x", "y", "z", "phi", "theta", "psi")), g)
    assert n == 1
    (d / f"{SYSTEM}.gains.toml").write_text(g)
    short_scenario(d, str(d / f"{SYSTEM}.toml"), 10.0)
    return d


def _study(d: Path, name: str, controllers: str, objectives_extra: str = "") -> Path:
    p = d / f"{name}.toml"
    p.write_text(small_study(name, controllers, seed=2, scale=2.0, population=4, generations=1,
                             reference_point=(5.0, 5.0), objectives=tuple(objectives_extra.splitlines()),
                             system=f"{SYSTEM}.toml", scenario="short.toml"), encoding="utf-8")
    return p


def test_a_pid_study_runs_to_the_end_where_the_agsta_defaults_diverge(system, capsys):
    study = _study(system, "pidonly", "pid")
    assert cli.main(["tune", str(study), "--out", str(system / "out")]) == 0
    out = capsys.readouterr().out
    said = "pid: objectives normalised by pid's value at the default gains of bluerov2_heavy_alpha5 on draw 1"
    assert said in out, out
    c = ck.read_checkpoint(system / "out" / "front.h5")
    assert c.status == "finished" and c.n_gen == 1
    assert c.normalisation == said.split("normalised by ")[1]
    np.testing.assert_allclose(c.table2_F, [1.0, 1.0], rtol=1e-12)  # the PID's defaults score (1, 1)


def test_given_values_are_the_normalisation(system, capsys):
    chat, rmse = [0.5, 0.5, 0.7, 0.01, 0.01, 0.02], [0.01, 0.01, 0.01, 0.03, 0.04, 0.05]
    study = _study(system, "given", "pid", f"normalisation_chat = {chat}\nnormalisation_rmse = {rmse}")
    assert cli.main(["tune", str(study), "--out", str(system / "given")]) == 0
    c = ck.read_checkpoint(system / "given" / "front.h5")
    assert c.normalisation == "the study's objectives.normalisation_chat and normalisation_rmse"
    np.testing.assert_array_equal(c.ref_chat, chat)
    np.testing.assert_array_equal(c.ref_rmse, rmse)
    # the defaults' objectives are their CHAT and RMSE over the given values, averaged over the DOF
    np.testing.assert_allclose(c.table2_F, [np.mean(c.table2_chat[0] / chat), np.mean(c.table2_rmse[0] / rmse)],
                               rtol=1e-12)
    assert load_study(study).identity("pid")["objectives"]["normalisation_chat"] == chat


def test_no_law_whose_defaults_run_is_one_line(system, capsys):
    study = _study(system, "agstanorm", "pid", 'normalisation = "agsta"')
    assert cli.main(["tune", str(study), "--out", str(system / "none")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "objectives.normalisation: no normalisation for the objectives on draw 1" in err \
        and "agsta at its default gains diverges at 1.5 s" in err and "normalisation_chat" in err, err
    assert not (system / "none" / "front.h5").exists()


@pytest.mark.parametrize("extra, key", [
    ("normalisation_chat = [1, 1, 1, 1, 1, 1]", "normalisation_rmse"),
    ('normalisation = "agsta"\nnormalisation_chat = [1, 1, 1, 1, 1, 1]\nnormalisation_rmse = [1, 1, 1, 1, 1, 1]',
     "normalisation"),
    ('normalisation = "not a law"', "normalisation"),
    ("normalisation_chat = [1, 1, 1, 1, 1, -1]\nnormalisation_rmse = [1, 1, 1, 1, 1, 1]", "normalisation_chat"),
    ("normalisation_chat = [1, 1, 1]\nnormalisation_rmse = [1, 1, 1, 1, 1, 1]", "normalisation_chat"),
])
def test_bad_normalisation_keys_are_refused_naming_the_key(system, extra, key, capsys):
    study = _study(system, "bad", "pid", extra)
    assert cli.main(["tune", str(study), "--out", str(system / "bad")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"objectives.{key}" in err, err


def test_the_page_names_the_normalisation_and_refuses_to_mix_two(system, capsys):
    import json

    if not (system / "out" / "front.h5").exists() or not (system / "given" / "front.h5").exists():
        pytest.skip("needs the two studies above")
    page = system / "pid.html"
    assert cli.main(["front", "explore", str(system / "out"), "--out", str(page)]) == 0
    m = re.search(r'<script type="application/json" id="data">(.*?)</script>', page.read_text(), re.S)
    doc = json.loads(m.group(1))
    assert doc["normalisation"] == "pid's value at the default gains of bluerov2_heavy_alpha5 on draw 1"
    assert "pid's value" in doc["objectives"][0]["description"]
    capsys.readouterr()
    assert cli.main(["front", "explore", str(system / "out"), str(system / "given"), "--out",
                     str(system / "mixed.html")]) == 2
    err = capsys.readouterr().err
    assert "normalised differently" in err and err.count("\n") == 1 and not (system / "mixed.html").exists()


def test_compare_refuses_fronts_normalised_differently(system):
    from arvcas.tuning.compare import compare_fronts
    from arvcas.tuning.front import read_front

    if not (system / "out" / "front.h5").exists() or not (system / "given" / "front.h5").exists():
        pytest.skip("needs the two studies above")
    a, b = read_front(system / "out"), read_front(system / "given")
    assert a.normalisation.startswith("pid's value") and b.normalisation.startswith("the study's")
    with pytest.raises(ValueError, match=r"^compare: the fronts' objectives are normalised differently \("):
        compare_fronts(a, b)
    assert compare_fronts(a, a).hv[0] == compare_fronts(a, a).hv[1]


def test_haidou1_named_or_not_is_one_study_and_a_changed_copy_is_its_own(tmp_path):
    """The default system takes the path every system takes: a study that names ``haidou1`` is recorded and
    normalised as one that names no system (the paper's Table 3); a copy of its file with other numbers is
    another system, recorded by its path and normalised by its own AGSTA."""
    from arvcas.system import result_ref
    from arvcas.tuning import run as tr

    def study(name: str, system: str | None) -> None:
        (tmp_path / f"{name}.toml").write_text(small_study("h", ["agsta"], seed=1, scale=2.0, population=4,
                                                           generations=1, reference_point=(5.0, 5.0),
                                                           system=system), encoding="utf-8")

    study("none", None)
    study("named", "haidou1")
    copy = tmp_path / "mine.toml"
    for f in ("haidou1.toml", "scenario.toml", "gains.toml"):
        shutil.copy(DATA / f, tmp_path / ("mine.toml" if f == "haidou1.toml" else f))
    study("copy", "mine.toml")
    studies = {k: load_study(tmp_path / f"{k}.toml") for k in ("none", "named", "copy")}
    assert [result_ref(s.params) for s in studies.values()] == ["", "", str(copy.resolve())]
    for k in ("none", "named"):
        assert tr.normalisation(studies[k], studies[k].params, None) == (None, "the paper's AGSTA value")
