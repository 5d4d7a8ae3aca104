"""`arvcas simulate` end to end: table, HDF5 file, one-line errors before any work."""

from __future__ import annotations

import numpy as np

from arvcas import cli
from arvcas.io import results
from arvcas.sim.simulation import simulate


def test_simulate_writes_result_and_prints_table(tmp_path, capsys):
    out = tmp_path / "run.h5"
    rc = cli.main(["simulate", "--controller", "proposed", "--seed", "3", "--out", str(out)])
    text = capsys.readouterr().out
    assert rc == 0
    assert "psi" in text and "CHAT" in text and "RMSE" in text
    r = results.read_result(out)
    ref = simulate("proposed", seed=3)
    np.testing.assert_array_equal(r.chat, ref.chat)
    np.testing.assert_array_equal(r.eta, ref.eta)
    assert r.seed == 3 and r.controller == "proposed"


def test_simulate_bad_inputs_one_line(tmp_path, capsys):
    cases = [
        (["simulate", "--controller", "lqr"], "unknown 'lqr'"),
        (["simulate", "--controller", "proposed", "--out", str(tmp_path / "missing" / "x.h5")], "does not exist"),
        (["simulate", "--controller", "proposed", "--config", str(tmp_path / "nope.toml")], "file not found"),
        (["simulate"], "--controller: required"),
    ]
    for argv, msg in cases:
        rc = cli.main(argv)
        err = capsys.readouterr().err
        assert rc == 2, argv
        assert msg in err and err.count("\n") == 1 and "Traceback" not in err, err
    assert not (tmp_path / "missing").exists()


def test_simulate_config_file_errors_name_the_key(tmp_path, capsys):
    from arvcas.sim.scenario import default_scenario_path

    bad = tmp_path / "s.toml"
    bad.write_text(default_scenario_path().read_text().replace("duration =", "durration ="))
    rc = cli.main(["simulate", "--controller", "proposed", "--config", str(bad)])
    err = capsys.readouterr().err
    assert rc == 2 and "unknown key 'time.durration'" in err and "did you mean 'time.duration'" in err
