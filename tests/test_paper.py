"""run_paper on a 5 s scenario: files, Table 3 markdown, real-run round trip, out_dir checks.

The three compiled 5 s runs are built once per module (first time ~15 s each; later from the build
cache, which is left as the environment sets it so CI's warm cache is reused).
"""

from __future__ import annotations

import dataclasses
import os
import stat

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from arvcas.experiments import paper  # noqa: E402
from arvcas.sim import scenario
from arvcas.io.results import ResultsError, read_result  # noqa: E402

DOF_MD = ("x", "y", "z", "φ", "θ", "ψ")


@pytest.fixture(scope="module")
def short_cfg():
    return dataclasses.replace(scenario.load_scenario(), time_duration=5.0)


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory, short_cfg):
    out = tmp_path_factory.mktemp("paper") / "out"  # does not exist yet: run_paper creates it
    messages: list[str] = []
    res = paper.run_paper(out, seed=0, progress=messages.append, cfg=short_cfg)
    return out, res, messages


def test_files_written(paper_run):
    out, res, messages = paper_run
    expected = ["proposed.h5", "agsta.h5", "traditional.h5", "table3.md", "ekf.md"] + [f"{f}.png" for f in paper.FIGURE_FILES]
    # and no temporary files left; the manifest records the text and PNG files arvcas wrote
    assert sorted(os.listdir(out)) == sorted(expected + [".arvcas-manifest.json"])
    for name in expected:
        assert (out / name).stat().st_size > 0
    assert set(res["files"]) == {"proposed", "agsta", "traditional", "table3", "ekf", *paper.FIGURE_FILES}
    ekf = (out / "ekf.md").read_text()
    assert ekf.count("\n| q_nu") + ekf.count("\n| no sensor noise") == len(paper.EKF_CASES)
    assert all(p.parent == out for p in res["files"].values())
    for name in paper.FIGURE_FILES:
        assert (out / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert messages and any("proposed" in m for m in messages)


def _main_table(text: str) -> list[list[str]]:
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("| DOF | CHAT AGSTA paper"))
    assert set(lines[start + 1].replace("|", "").replace("-", "").replace(":", "")) <= {" ", ""}
    rows = []
    for ln in lines[start + 2:]:
        if not ln.startswith("|"):
            break
        rows.append([c.strip() for c in ln.strip("|").split("|")])
    return rows


def test_table3_markdown(paper_run):
    out, res, _ = paper_run
    text = (out / "table3.md").read_text(encoding="utf-8")
    rows = _main_table(text)
    assert [r[0] for r in rows] == list(DOF_MD)  # six DOF rows, in the paper's order
    assert all(len(r) == 13 for r in rows)
    p, a = res["results"]["proposed"], res["results"]["agsta"]
    for i, r in enumerate(rows):
        assert float(r[1]) == pytest.approx([0.0363, 0.0749, 0.1045, 0.0903, 0.1173, 0.1006][i])
        assert float(r[4]) == pytest.approx(a.chat[i], rel=1e-3) and float(r[5]) == pytest.approx(p.chat[i], rel=1e-3)
        assert float(r[6]) == pytest.approx(p.chat[i] / a.chat[i], abs=1e-3)
        assert float(r[12]) == pytest.approx(p.rmse[i] / a.rmse[i], abs=1e-3)
    # one comparison line per DOF, consistent with the returned checks
    for i, d in enumerate(DOF_MD):
        line = next(ln for ln in text.splitlines() if ln.startswith(f"- {d}: "))
        c = res["checks"][paper._DOFS[i]]
        assert ("CHAT proposed < AGSTA: yes" in line) == c["chat_lower"]
        assert ("RMSE proposed <= 1.1 x AGSTA: yes" in line) == c["rmse_ok"]
    assert res["passed"] == all(c["chat_lower"] and c["rmse_ok"] for c in res["checks"].values())


def test_result_files_round_trip_real_runs(paper_run, short_cfg):
    out, res, _ = paper_run
    for c in paper.CONTROLLERS:
        r, back = res["results"][c], read_result(out / f"{c}.h5")
        assert back.controller == c and back.seed == 0 and back.ok == r.ok
        assert back.t[-1] == pytest.approx(short_cfg.time_duration)
        for name in ("t", "eta", "eta_ref", "tau_cmd", "thrust", "s", "k1", "f_hat", "f_true", "chat", "rmse", "gains",
                     "params_vector", "uncertainty", "phase"):
            np.testing.assert_array_equal(getattr(back, name), getattr(r, name), err_msg=f"{c}.{name}")
        assert back.config_text == r.config_text


def test_unwritable_out_dir_refused_before_running(tmp_path, monkeypatch, short_cfg):
    def no_simulation(*a, **k):
        raise AssertionError("simulate must not run when out_dir is unusable")

    monkeypatch.setattr(paper, "simulate", no_simulation)
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(ResultsError) as e:
            paper.run_paper(ro, progress=None, cfg=short_cfg)
        assert "\n" not in str(e.value) and str(ro) in str(e.value)
    finally:
        ro.chmod(stat.S_IRWXU)
    f = tmp_path / "afile"
    f.write_text("x")
    with pytest.raises(ResultsError, match="not a directory"):
        paper.run_paper(f, progress=None, cfg=short_cfg)
    with pytest.raises(ResultsError):
        paper.run_paper(f / "sub", progress=None, cfg=short_cfg)
