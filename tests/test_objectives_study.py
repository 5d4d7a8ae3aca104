"""A study of three objectives and a thrust constraint through NSGA-III: resumes bit for bit, its front exports,
plots, knees and compares; the paper's studies keep their identity and evaluation (docs/objectives.md)."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from arvcas.sim import scenario
from arvcas.tuning import checkpoint as ck
from arvcas.tuning.front import export_front, knee_index, read_front
from arvcas.tuning.run import eval_task, run_study
from arvcas.tuning.study import loads_study
from studytext import tiny_study

ROOT = Path(__file__).resolve().parents[1]


def quiet(_msg: str) -> None:
    pass


def study_text(tmp: Path, population: int = 8, generations: int = 3) -> str:
    """The tiny study on a 3 s scenario, three objectives, peak thrust within 95 % of each thruster's limit."""
    scen = tmp / "short.toml"
    scen.write_text(dataclasses.replace(scenario.load_scenario(), time_duration=3.0).to_toml())
    return (tiny_study(population=population, generations=generations)
            .replace('name = "nsga2"\n', 'name = "nsga3"\n')
            .replace('names = ["chat", "rmse"]\nreference_point = [300.0, 4.0]',
                     'names = ["chat", "rmse", "energy"]\nreference_point = [300.0, 4.0, 1e5]\n'
                     'constraints = ["peak_thrust <= 0.95 * limit"]')
            .replace("[evaluation]\n", '[evaluation]\nscenario = "short.toml"\n'))


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("nsga3")
    warnings.simplefilter("ignore", scenario.ScenarioWarning)  # the 3 s copy has the 100 s run's events
    text = study_text(tmp)
    (tmp / "s.toml").write_text(text)
    study = loads_study(text, str(tmp / "s.toml"), base_dir=tmp)
    run_study(study, tmp / "a", say=quiet)
    return tmp, study, ck.read_checkpoint(tmp / "a" / "front.h5")


def test_three_objectives_with_a_constraint(uninterrupted):
    tmp, study, c = uninterrupted
    assert c.F.shape == (8, 3) and c.G.shape == (8, 2) and c.survival
    feas = (c.G <= 0).all(axis=1)
    assert 0 < feas.sum() < 8  # the constraint decides: some members violate it, some keep it
    assert set(c.front) <= set(np.flatnonzero(feas))
    # the constraint column is the peak thrust's relative excess over 95 % of the limit: recomputed from the
    # accumulator run of the front's first member
    from arvcas.metrics import objectives as O
    from arvcas.sim.simulation import compiled_run

    task = eval_task(study, "agsta")
    run = compiled_run("agsta", task.params, task.cfg, accumulators=task.accumulators)
    i = int(c.front[0])
    out = run.outputs(c.gains[i:i + 1], seed=0, n_threads=1)
    ctx = O.Context(cfg=task.cfg, params=task.params, ref=None, chat="chat",
                    slices=O.slices(task.accumulators, task.params.structure.n_thrusters, task.cfg))
    pk = O.get("peak_thrust")
    el, lim = pk.elements(out, ctx)[0], pk.limit(ctx)
    assert c.G[i, 1] == pytest.approx(((el - 0.95 * lim) / (0.95 * lim)).max(), rel=1e-12)
    assert c.F[i, 2] == pytest.approx(O.get("energy").values(out, ctx)[0], rel=1e-12)


def test_resume_is_bit_for_bit(uninterrupted):
    tmp, study, a = uninterrupted
    run_study(study, tmp / "b", say=quiet, stop_after=1)
    run_study(study, tmp / "b", say=quiet, resume=True)
    b = ck.read_checkpoint(tmp / "b" / "front.h5")
    for k in ("X", "F", "G", "rank"):
        assert np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True), k
    assert a.rng_state == b.rng_state and a.survival == b.survival
    assert np.array_equal(a.history["hv"], b.history["hv"])


def test_front_exports_plots_knees_and_compares(uninterrupted, tmp_path):
    tmp, _, c = uninterrupted
    path = tmp / "a" / "front.h5"
    fr = read_front(path)
    assert fr.labels == ["f_chat", "f_rmse", "f_energy"] and fr.size == c.front.size > 0
    rows = list(csv.DictReader(io.StringIO(export_front(path, "csv"))))
    assert [float(r["f_energy"]) for r in rows] == fr.F[:, 2].tolist()
    doc = json.loads(export_front(path, "json"))
    assert doc["objectives"] == fr.labels and doc["members"][0]["f_energy"] == fr.F[0, 2]
    # the knee rule for m objectives: pseudo-weights closest to (1/3, 1/3, 1/3)
    F = fr.F
    span = np.where(F.max(0) > F.min(0), F.max(0) - F.min(0), 1.0)
    w = (F.max(0) - F) / span
    w = w / w.sum(axis=1, keepdims=True)
    if fr.size > 1 and (F.max(0) > F.min(0)).all():
        assert knee_index(F) == int(np.argmin(np.linalg.norm(w - 1 / 3, axis=1)))
    fig = fr.plot()
    assert len([ax for ax in fig.axes if ax.get_visible()]) == 3  # one panel per pair of objectives
    from arvcas.tuning.compare import compare_fronts, format_comparison

    cmp = compare_fronts(path, path)
    assert cmp.hv[0] == cmp.hv[1] == fr.hv and cmp.regions == ()
    assert "reference point (f_chat, f_rmse, f_energy)" in format_comparison(cmp)


def test_paper_studies_keep_their_identity_and_evaluation():
    """Every committed front's study, read by this arvcas, has the identity stored in the front (what
    --resume compares) in everything the objectives or the algorithm shape, and evaluates as before (no
    accumulators: the compiled run of the paper)."""
    warnings.simplefilter("ignore", scenario.ScenarioWarning)
    fronts = sorted(ROOT.glob("results/**/front.h5"))
    assert len(fronts) >= 6
    for f in fronts:
        c = ck.read_checkpoint(f)
        s = loads_study(c.study_text, c.study_path, base_dir=ROOT / Path(c.study_path).parent)
        new, old = json.loads(s.identity_json(c.controller)), json.loads(c.identity)
        for k in ("objectives", "algorithm", "variables", "draws", "seed"):
            assert new[k] == old[k], (f, k)
        assert s.objectives.default  # eval_task then gives no accumulators: the paper's compiled run
