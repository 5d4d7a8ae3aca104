"""A study on another system end to end (issue 12): a tiny NSGA-II study of the BlueROV2 Heavy + Reach
Alpha 5, its checkpoint naming the system and the normalisation, the knee replayed bit for bit by
`arvcas knees`, and `arvcas simulate --from-front` taking the front's system."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import arvcas
from arvcas import cli
from arvcas.sim import scenario
from arvcas.tuning import checkpoint as ck
from arvcas.tuning import load_study


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("b2study")
    s = arvcas.load_system("bluerov2_heavy_alpha5")
    cfg = replace(scenario.load_scenario(s.params.default("scenario")), time_duration=20.0)
    (d / "short.toml").write_text(cfg.to_toml(), encoding="utf-8")
    (d / "study.toml").write_text("""
[study]
name = "b2tiny"
controllers = ["proposed", "agsta"]
seed = 5
[variables]
scale = 3.0
[algorithm]
population = 6
include_table2 = true
[termination]
max_generations = 2
[objectives]
names = ["chat", "rmse"]
reference_point = [2.0, 2.0]
[evaluation]
system = "bluerov2_heavy_alpha5"
scenario = "short.toml"
[[evaluation.draws]]
noise_seed = 1
""", encoding="utf-8")
    assert cli.main(["tune", str(d / "study.toml"), "--out", str(d / "out")]) == 0
    return d


def test_study_runs_on_its_system(study_dir):
    st = load_study(study_dir / "study.toml")
    assert st.params.structure.name == "bluerov2_heavy_alpha5" and st.identity("agsta")["system"] == st.params.structure.name
    c = ck.read_checkpoint(study_dir / "out" / "agsta" / "front.h5")
    assert c.system == "bluerov2_heavy_alpha5" and c.params.size == len(st.params)
    # the normalisation is this system's AGSTA at its defaults on the draw: the defaults score (1, 1)
    np.testing.assert_allclose(c.table2_F, [1.0, 1.0], rtol=1e-12)
    np.testing.assert_allclose(c.table2_chat[0], c.ref_chat, rtol=0)
    np.testing.assert_allclose(c.table2_rmse[0], c.ref_rmse, rtol=0)


def test_knees_replay_bit_for_bit(study_dir):
    out = study_dir / "knees"
    assert cli.main(["knees", str(study_dir / "out"), "--out", str(out)]) == 0  # raises if a replay differs
    from arvcas.io.results import read_result

    r = read_result(out / "knee_proposed.h5")
    assert r.meta["system"] == "bluerov2_heavy_alpha5" and r.thrust.shape[1] == 8 and r.q.shape[1] == 4
    text = (out / "knees.md").read_text()
    assert "Saturation envelope of bluerov2_heavy_alpha5" in text and "| proposed |" in text
    for n in ("knees_states.png", "knees_errors.png", "knees_thrust.png"):
        assert (out / n).stat().st_size > 10_000


def test_simulate_from_front_takes_the_fronts_system(study_dir, capsys):
    front = study_dir / "out" / "proposed"
    assert cli.main(["simulate", "--from-front", str(front), "--index", "0"]) == 0
    assert "proposed: seed 1, 20 s, ok" in capsys.readouterr().out


def test_montecarlo_on_another_system_reproduces_from_its_file(study_dir):
    """`arvcas montecarlo --system ...` stores its system; `--check` re-runs it bit for bit."""
    out = study_dir / "mc.h5"
    assert cli.main(["montecarlo", "--system", "bluerov2_heavy_alpha5", "--controller", "proposed", "--runs", "3",
                     "--seed", "4", "--config", str(study_dir / "short.toml"), "--out", str(out)]) == 0
    from arvcas.experiments.montecarlo import read_montecarlo

    mc = read_montecarlo(out)
    assert mc.meta["system"] == "bluerov2_heavy_alpha5" and mc.meta["reference"] is not None
    assert np.isfinite(mc.objectives()).all()
    assert cli.main(["montecarlo", "--check", str(out)]) == 0
