"""Study files: every bad input is a one-line error naming file and key, before any work."""

from __future__ import annotations

import os
import time

import pytest

from arvcas import cli
from arvcas.tuning import load_study, loads_study
from arvcas.tuning.study import StudyError
from studytext import tiny_study

def tiny_text(controller="agsta", seed=3, population=8, generations=3, **_) -> str:
    return tiny_study(controller=controller, seed=seed, population=population, generations=generations)


def write_tiny(path, **kw):
    path.write_text(tiny_text(**kw))
    return path


def test_shipped_studies_load():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "studies"
    names = {p.stem for p in root.glob("*.toml")}
    assert {"quick", "paper", "gamultiobj-defaults"} <= names
    for p in sorted(root.glob("*.toml")):
        s = load_study(p)
        for c in s.controllers:
            names_, lo, hi, g0 = s.bounds(c)
            assert len(names_) == s.n_var(c) and (lo <= g0).all() and (g0 <= hi).all()
    g = load_study(root / "gamultiobj-defaults.toml")
    assert g.algorithm.population == 200 and g.termination.max_generations_per_variable == 200
    assert g.termination.stall_generations == 100 and g.termination.ftol == 1e-4
    assert g.termination.generations(48) == 9600


def test_tiny_study_values(tmp_path):
    s = load_study(write_tiny(tmp_path / "s.toml"))
    assert s.controllers == ("agsta",) and s.seed == 3 and s.algorithm.population == 8
    assert s.algorithm.n_offspring == 8 and s.termination.generations(48) == 3
    names, lo, hi, g0 = s.bounds("agsta")
    assert names[0] == "x.c" and lo[0] == g0[0] / 2 and hi[0] == g0[0] * 2
    assert s.identity("agsta")["seed"] == 3


def _sub(old, new):
    return lambda t: t.replace(old, new, 1)


# (label, transform of the tiny study text, expected fragment of the one-line message)
BAD_TEXT = [
    ("malformed", lambda t: t + "\n[[[nope\n", "malformed TOML"),
    ("unknown key", _sub("population = 8", "populaton = 8"), "unknown key 'algorithm.populaton' (did you mean 'algorithm.population'?)"),
    ("unknown section", _sub("[engine]", "[engin]"), "unknown section 'engin' (did you mean 'engine'?)"),
    ("missing key", _sub("seed = 3\n", ""), "missing key 'study.seed'"),
    ("missing section", _sub("[objectives]\nnames = [\"chat\", \"rmse\"]\nreference_point = [300.0, 4.0]\n", ""),
     "missing section [objectives]"),
    ("wrong type", _sub("population = 8", 'population = "8"'), "algorithm.population: must be an integer, got string"),
    ("float for int", _sub("population = 8", "population = 8.0"), "algorithm.population: must be an integer"),
    ("population < 4", _sub("population = 8", "population = 3"), "algorithm.population: must be >= 4"),
    ("nan", _sub("scale = 2.0", "scale = nan"), "variables.scale: must be finite"),
    ("inf", _sub("reference_point = [300.0, 4.0]", "reference_point = [inf, 4.0]"), "objectives.reference_point: must be finite"),
    ("negative", _sub("reference_point = [300.0, 4.0]", "reference_point = [300.0, -4.0]"), "objectives.reference_point: must be > 0"),
    ("zero generations", _sub("max_generations = 3", "max_generations = 0"), "termination.max_generations: must be >= 1"),
    ("scale <= 1", _sub("scale = 2.0", "scale = 1.0"), "variables.scale: must be > 1"),
    ("no end", _sub("max_generations = 3\n", ""), "a study must end"),
    ("lower >= upper", _sub("scale = 2.0", "scale = 2.0\nbounds = { c = [5.0, 1.0] }"), "variables.bounds.c: lower bound 5.0 must be < upper bound 1.0"),
    ("lower <= 0", _sub("scale = 2.0", "scale = 2.0\nbounds = { c = [0.0, 1.0] }"), "lower bound must be > 0"),
    ("excludes Table 2", _sub("scale = 2.0", "scale = 2.0\nbounds = { c = [3.0, 10.0] }"),
     "variables.bounds.c: [3, 10] does not contain Table 2's agsta x.c = 2.55"),
    ("unknown gain", _sub("scale = 2.0", "scale = 2.0\nbounds = { omgea = [0.1, 1.0] }"), "unknown key 'variables.bounds.omgea'"),
    ("unknown controller", _sub('controllers = "agsta"', 'controllers = "agst"'),
     "study.controllers: unknown controller 'agst' (did you mean 'agsta'?)"),
    ("unknown engine", _sub('name = "local"', 'name = "dusk"'), "engine.name: unknown engine 'dusk' (did you mean 'dask'?)"),
    ("wrong objectives", _sub('names = ["chat", "rmse"]', 'names = ["rmse"]'),
     "objectives.names: must list at least 2 (a study takes 2 to 4 objectives), got 1"),
    ("unknown objective", _sub('names = ["chat", "rmse"]', 'names = ["chat", "enrgy"]'),
     "objectives.names: unknown objective 'enrgy' (did you mean 'energy'?) (allowed: chat, rmse, iae, energy"),
    ("five objectives", _sub('names = ["chat", "rmse"]\nreference_point = [300.0, 4.0]',
                             'names = ["chat", "rmse", "iae", "energy", "excursion"]\nreference_point = [1, 1, 1, 1, 1]'),
     "objectives.names: must list at most 4 (a study takes 2 to 4 objectives), got 5"),
    ("reference point length", _sub('names = ["chat", "rmse"]\nreference_point = [300.0, 4.0]',
                                    'names = ["chat", "energy"]\nreference_point = [300.0, 4.0, 1.0]'),
     "objectives.reference_point: 3 values for 2 objectives (chat, energy): give one per objective"),
    ("malformed constraint", _sub('names = ["chat", "rmse"]', 'names = ["chat", "rmse"]\nconstraints = ["peak_thrust = 1"]'),
     "objectives.constraints: 'peak_thrust = 1' is not a constraint (allowed forms: 'name <= number'"),
    ("three objectives need nsga3", _sub('names = ["chat", "rmse"]\nreference_point = [300.0, 4.0]',
                                         'names = ["chat", "rmse", "energy"]\nreference_point = [1, 1, 1]'),
     'algorithm.name: 3 objectives need "nsga3"'),
    ("draw key", _sub("noise_seed = 0", "noise_sed = 0"), "unknown key 'evaluation.draws.noise_sed'"),
    ("negative seed", _sub("seed = 3", "seed = -1"), "study.seed: must be >= 0"),
    ("bool for int", _sub("seed = 3", "seed = true"), "study.seed: must be an integer, got boolean"),
    ("scenario missing", _sub("[evaluation]", '[evaluation]\nscenario = "nope.toml"'), "evaluation.scenario:"),
    ("scheduler for local", _sub('name = "local"', 'name = "local"\nscheduler = "tcp://x:1"'),
     "engine.scheduler: only for engine.name = \"dask\""),
]


@pytest.mark.parametrize("label,edit,msg", BAD_TEXT, ids=[b[0] for b in BAD_TEXT])
def test_bad_study_is_one_line_before_any_work(tmp_path, capsys, label, edit, msg):
    study = tmp_path / "s.toml"
    study.write_text(edit(tiny_text()))
    out = tmp_path / "out"
    rc = cli.main(["tune", str(study), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert msg in err, err
    assert str(study) in err
    assert not out.exists()  # nothing written


def test_omega_bound_must_keep_reso_stable(tmp_path):
    text = tiny_text(controller="proposed").replace("scale = 2.0", "scale = 2.0\nbounds = { omega = [0.1, 25.0] }")
    with pytest.raises(StudyError, match=r"variables.bounds.omega: upper bound 25 .* need upper < 20"):
        loads_study(text, "s.toml")


def test_file_level_errors(tmp_path, capsys):
    bad_utf8 = tmp_path / "latin1.toml"
    bad_utf8.write_bytes(tiny_text().replace('"tiny"', '"t\u00e9st"').encode("latin-1"))
    cases = [
        (tmp_path / "missing.toml", "study file not found"),
        (tmp_path, "is a directory"),
        (bad_utf8, "not UTF-8 text"),
    ]
    for path, msg in cases:
        rc = cli.main(["tune", str(path), "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert rc == 2 and msg in err and err.count("\n") == 1, err
    assert not (tmp_path / "o").exists()


def test_output_directory_errors(tmp_path, capsys):
    study = write_tiny(tmp_path / "s.toml")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        cases = [
            (tmp_path / "missing" / "out", "parent directory"),
            (ro / "out", "is not writable"),
            (ro, "is not writable"),
            (study, "exists and is not a directory"),
        ]
        for out, msg in cases:
            rc = cli.main(["tune", str(study), "--out", str(out)])
            err = capsys.readouterr().err
            assert rc == 2 and msg in err and err.count("\n") == 1, err
    finally:
        ro.chmod(0o755)
    assert not (tmp_path / "missing").exists() and not (ro / "out").exists()


def test_cli_override_errors(tmp_path, capsys):
    study = write_tiny(tmp_path / "s.toml")
    for argv, msg in [
        (["--engine", "local", "--scheduler", "tcp://127.0.0.1:1"], "--scheduler: only with --engine dask"),
        (["--threads", "0"], "--threads: 0 is out of range (allowed: 1..1024)"),
        (["--controller", "proposed"], "--controller proposed: not in the study's controllers (agsta)"),
    ]:
        rc = cli.main(["tune", str(study), "--out", str(tmp_path / "o"), *argv])
        err = capsys.readouterr().err
        assert rc == 2 and msg in err and err.count("\n") == 1, err


def test_unreachable_scheduler_errors_within_timeout(tmp_path, capsys):
    pytest.importorskip("distributed")
    study = write_tiny(tmp_path / "s.toml")
    t0 = time.monotonic()
    rc = cli.main(["tune", str(study), "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:1",
                   "--timeout", "2"])
    dt = time.monotonic() - t0
    err = capsys.readouterr().err
    assert rc == 2 and "cannot connect to scheduler tcp://127.0.0.1:1" in err and err.count("\n") == 1, err
    assert dt < 20
    # the directory was created and locked, but holds no checkpoint and no lock file afterwards
    assert os.listdir(tmp_path / "o") == []
