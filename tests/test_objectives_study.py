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


def _union_volume(P: np.ndarray, ref: np.ndarray) -> float:
    """Volume of the union of the boxes [p, ref], by inclusion-exclusion over the subsets of P's rows."""
    total = 0.0
    for mask in range(1, 2 ** len(P)):
        rows = [i for i in range(len(P)) if mask >> i & 1]
        total += (-1) ** (len(rows) + 1) * np.prod(ref - P[rows].max(axis=0))
    return float(total)


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
    assert fr.size >= 2 and (F.max(0) > F.min(0)).all(), F  # a front on which the rule has a choice to make
    assert knee_index(F) == int(np.argmin(np.linalg.norm(w - 1 / 3, axis=1)))
    fig = fr.plot()
    assert len([ax for ax in fig.axes if ax.get_visible()]) == 3  # one panel per pair of objectives
    from arvcas.tuning.compare import compare_fronts, format_comparison

    # against the same front less one member, both inside a reference point that every member dominates:
    # members of a non-dominated set do not dominate each other, so the smaller front covers (n - 1) / n of
    # the whole and is covered entirely; the hypervolumes are the volumes of the unions of the members'
    # boxes, by inclusion-exclusion (each member adds volume of its own: the whole front's is larger)
    keep = np.flatnonzero(np.arange(fr.size) != knee_index(F))
    less = dataclasses.replace(fr, F=F[keep], G=fr.G[keep], gains=fr.gains[keep], X=fr.X[keep])
    ref = F.max(0) + (F.max(0) - F.min(0))
    cmp = compare_fronts(fr, less, ref=ref)
    assert cmp.sizes == (fr.size, fr.size - 1) and cmp.regions == ()
    assert cmp.hv == pytest.approx((_union_volume(F, ref), _union_volume(F[keep], ref)), rel=1e-9)
    assert cmp.hv[0] > cmp.hv[1] and cmp.better == cmp.labels[0]
    assert cmp.coverage == (1.0, pytest.approx((fr.size - 1) / fr.size, rel=1e-12))
    assert compare_fronts(fr, less).hv[0] == fr.hv  # by default, against the studies' reference point
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


# ---- a user's objective from a --plugin file, through the command line ---------------------------------------

USER_OBJECTIVE = '''\
"""A lab's objective (a test's plugin): the integrated absolute heave and yaw error, weighted."""
import casadi as ca

from arvcas.metrics.objectives import Objective
from arvcas.sim.accumulate import Accumulator


def heave_yaw(v):
    return ca.vertcat(v.h * ca.fabs(v.e[2]), v.h * ca.fabs(v.e[5]))


class HeaveYaw(Objective):
    name, unit = "lab_heave_yaw", "m s"
    description = "integrated |heave error| + 0.5 m/rad x integrated |yaw error|"
    accumulators = (Accumulator("lab_heave_yaw", "sum", 2, heave_yaw),)

    def values(self, out, ctx):
        a = ctx.acc(out, "lab_heave_yaw")
        return a[:, 0] + 0.5 * a[:, 1]
'''


@pytest.mark.filterwarnings("ignore::arvcas.sim.scenario.ScenarioWarning")  # the 3 s copy keeps the 100 s run's events
def test_a_plugin_objective_tunes_through_the_command_line(tmp_path, capsys, fresh):
    """``arvcas tune STUDY --plugin toy_objective.py`` with the plugin's objective beside RMSE: the study runs
    (NSGA-II, 6 candidates, 2 generations, a 3 s scenario), its front exports the objective's column, and
    every member's value is the plugin's ``values`` applied to its replayed run (bit for bit), which is
    the weighted integral of the traced error of ``simulate --from-front`` (to 1e-12)."""
    from arvcas import cli
    from arvcas.metrics import objectives as O
    from arvcas.io.results import read_result
    from arvcas.sim.run import Run

    plugin = tmp_path / "toy_objective.py"
    plugin.write_text(USER_OBJECTIVE)
    (tmp_path / "short.toml").write_text(
        dataclasses.replace(scenario.load_scenario(), time_duration=3.0).to_toml())
    study = tmp_path / "s.toml"
    study.write_text(tiny_study(population=6, generations=2)
                     .replace('names = ["chat", "rmse"]\nreference_point = [300.0, 4.0]',
                              'names = ["rmse", "lab_heave_yaw"]\nreference_point = [4.0, 10.0]')
                     .replace("[evaluation]\n", '[evaluation]\nscenario = "short.toml"\n'))

    def cmd(*argv):
        rc = cli.main([str(a) for a in argv])
        out = capsys.readouterr()
        assert rc == 0, out.err
        return out.out

    # without the plugin the study's objective is unknown: one line, nothing written
    assert cli.main(["tune", str(study), "--out", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "lab_heave_yaw" in err and not (tmp_path / "none").exists(), err
    cmd("tune", study, "--out", tmp_path / "out", "--plugin", plugin)
    assert O.origin("lab_heave_yaw")["kind"] == "file"
    path = tmp_path / "out" / "front.h5"
    fr = read_front(path)
    assert fr.objectives == ("rmse", "lab_heave_yaw") and fr.labels == ["f_rmse", "f_lab_heave_yaw"]
    assert fr.size >= 1 and np.isfinite(fr.F).all()
    rows = list(csv.DictReader(io.StringIO(cmd("front", "export", path, "--format", "csv"))))
    assert [float(r["f_lab_heave_yaw"]) for r in rows] == fr.F[:, 1].tolist()  # repr round-trips a float
    # the members' runs replayed with the objective's accumulators: the plugin's function gives the column
    obj = O.get("lab_heave_yaw")
    cfg = scenario.loads_scenario(fr.scenario_text)
    run = Run(fr.controller, cfg, accumulators=O.accumulators_of([obj])).compile()
    out = run.outputs(fr.gains, seed=int(fr.draw_seeds[0]), uncertainty=fr.draw_uncertainty[0],
                      phase=fr.draw_phase[0], n_threads=1)
    ctx = O.Context(cfg=cfg, params=run.params, ref=None, chat="chat",
                    slices=O.slices(run.accumulators, run.params.structure.n_thrusters, cfg))
    got = obj.values(out, ctx)
    assert out["ok"].all() and (got > 0).all()
    np.testing.assert_array_equal(got, fr.F[:, 1])
    # and from the trace of the command line's replay: h sum_k (|e_z| + 0.5 |e_psi|), k = 0 .. N-1
    for i in sorted({0, fr.size - 1}):
        r_path = tmp_path / f"replay{i}.h5"
        cmd("simulate", "--from-front", path, "--index", i, "--out", r_path)
        r = read_result(r_path)
        assert r.t[-1] == pytest.approx(3.0)
        e = (r.eta - r.eta_ref)[:scenario.n_samples(cfg) - 1]
        want = cfg.time_h * (np.abs(e[:, 2]).sum() + 0.5 * np.abs(e[:, 5]).sum())
        assert fr.F[i, 1] == pytest.approx(want, rel=1e-12, abs=0), (i, fr.F[i, 1], want)
        np.testing.assert_array_equal(r.rmse, fr.rmse[0, i])
