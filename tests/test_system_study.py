"""A study on another system end to end: a tiny NSGA-II study of the BlueROV2 Heavy + Reach
Alpha 5, its checkpoint naming the system and the normalisation, the knee replayed bit for bit by
`arvcas knees`, and `arvcas simulate --from-front` taking the front's system."""

from __future__ import annotations

import base64
import json
import re
import shutil

import numpy as np
import pytest

import arvcas
import arvcas.tuning
from arvcas import cli
from arvcas.sim import scenario
from arvcas.tuning import checkpoint as ck
from arvcas.tuning import load_study

from studytext import short_scenario, small_study
from trust_helpers import HOSTILE, chromium, page_faults


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("b2study")
    short_scenario(d, "bluerov2_heavy_alpha5", 20.0)
    (d / "study.toml").write_text(small_study("b2tiny", ["proposed", "agsta"], seed=5, scale=3.0, population=6,
                                              generations=2, include_table2=True, system="bluerov2_heavy_alpha5",
                                              scenario="short.toml"), encoding="utf-8")
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


# ---- the front explorer and the outputs' labels ------------------------------------------------------------------

PAPER_NAMES = re.compile(r"Table \d|Table A\d|the paper's|paper Table|\(Fig\. \d+")


def _page_data(page):
    text = page.read_text(encoding="utf-8")
    m = re.search(r'<script type="application/json" id="data">(.*?)</script>', text, re.S)
    return json.loads(m.group(1).replace("<\\/", "</"))


def _unpack(p: dict, width: int) -> np.ndarray:
    q = np.frombuffer(base64.b64decode(p["q"]), dtype="<u2").reshape(-1, width).astype(float)
    out = np.asarray(p["lo"]) + np.asarray(p["step"]) * q
    out[q == 65535] = np.nan
    return out


def _chromium(args):
    """Headless Chromium (the Debian package) on a fresh profile; returns (stdout, stderr)."""
    r = chromium(args)
    if r is None:
        pytest.skip("chromium is not installed (Debian: apt-get install chromium; .ci/run installs it)")
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout, r.stderr


@pytest.fixture(scope="module")
def page(study_dir):
    out = study_dir / "front.html"
    assert cli.main(["front", "explore", str(study_dir / "out"), "--out", str(out)]) == 0
    return out


def test_explore_page_holds_every_front_and_the_members_own_responses(study_dir, page):
    from arvcas.tuning.front import read_front

    doc = _page_data(page)
    assert doc["system"] == "bluerov2_heavy_alpha5" and [f["controller"] for f in doc["fronts"]] == ["agsta", "proposed"]
    assert [(o["label"], o["log"]) for o in doc["objectives"]] == [("f_chat (mean CHAT, normalised)", True),
                                                                   ("f_rmse (mean RMSE, normalised)", True)]
    for f in doc["fronts"]:
        fr = read_front(study_dir / "out" / f["controller"])
        assert f["F"] == fr.F.tolist() and f["knee"] == fr.knee() and f["thrusters"] == [f"T{i}" for i in range(1, 9)]
        assert sorted(f["traces"], key=str) == sorted([str(i) for i in range(fr.size)] + ["defaults"], key=str)
        assert f["replay"]["reproduced"] and f["replay"]["max_difference"] == 0.0  # replays checked bit for bit
    # one member's stored response against an independent replay (arvcas simulate --from-front's path)
    f = doc["fronts"][1]
    i = f["knee"]
    controller, gains, seed, cfg_text = arvcas.tuning.member_gains(study_dir / "out" / "proposed", i)
    s = arvcas.load_system("bluerov2_heavy_alpha5")
    r = arvcas.simulate(controller, gains=gains, seed=seed, system=s.params,
                        cfg=scenario.loads_scenario(cfg_text))
    keep = np.rint(np.asarray(f["t"]) / r.h).astype(int)
    for key, ref in (("e", (r.eta - r.eta_ref)[keep]), ("u", np.asarray(r.thrust)[keep])):
        got = _unpack(f["traces"][str(i)][key], ref.shape[1])
        step = np.asarray(f["traces"][str(i)][key]["step"])
        assert got.shape == ref.shape and np.all(np.abs(got - ref) <= 0.5 * step * (1 + 1e-9) + 1e-300)


def test_explore_page_loads_in_headless_chromium_without_console_errors(page, tmp_path):
    shot = tmp_path / "shot.png"
    dom, err = _chromium(["--window-size=1280,1100", f"--screenshot={shot}", "--dump-dom", page.as_uri()])
    assert not page_faults(dom, err)  # no console line (error, warning, uncaught exception); its script ran to the end
    from matplotlib.image import imread

    img = (imread(shot)[..., :3] * 255).round()
    assert img.shape[:2] == (1100, 1280)
    assert (np.abs(img - 255).sum(axis=2) > 30).mean() > 0.03  # not blank
    top = img[:600]  # the front plot
    for f in _page_data(page)["fronts"]:
        rgb = np.array([int(f["color"][k:k + 2], 16) for k in (1, 3, 5)], dtype=float)
        near = (np.abs(top - rgb).max(axis=2) <= 12).sum()
        assert near > 150, (f["controller"], f["color"], near)  # every front is drawn in its colour


_STRUCTURAL = {"q", "color", "dofs", "format", "format_version", "arvcas_version"}  # written by arvcas, not by users


def _hostile(doc, payload):
    """``doc`` with ``payload`` put in front of every string a user can control (every string but the page's
    own structure: encoded traces, colours, DOF names, format tags)."""
    if isinstance(doc, dict):
        return {k: v if k in _STRUCTURAL else _hostile(v, payload) for k, v in doc.items()}
    if isinstance(doc, list):
        return [_hostile(v, payload) for v in doc]
    return payload + doc if isinstance(doc, str) else doc


def _check_hostile_page(page, payload):
    dom, err = _chromium(["--window-size=1280,1100", "--dump-dom", page.as_uri()])
    assert not page_faults(dom, err, payload)  # loads, runs to the end, shows the name as text and runs nothing


@pytest.mark.parametrize("payload", HOSTILE)
def test_explore_page_shows_hostile_names_as_text_and_runs_nothing(page, tmp_path, payload):
    from arvcas.experiments.explore import inline_json, page_html

    doc = _hostile(_page_data(page), payload)
    text = page_html(doc)
    data = re.search(r'<script type="application/json" id="data">(.*?)</script>', text, re.S).group(1)
    assert "<" not in data and ">" not in data and "&" not in data and json.loads(data) == doc == json.loads(
        inline_json(doc))
    out = tmp_path / "hostile.html"
    out.write_text(text, encoding="utf-8")
    _check_hostile_page(out, payload)


def test_explore_page_of_a_study_directory_with_a_hostile_name(study_dir, tmp_path):
    payload = HOSTILE[0]
    d = tmp_path / payload
    shutil.copytree(study_dir / "out" / "agsta", d)
    out = tmp_path / "p.html"
    assert cli.main(["front", "explore", str(d), "--out", str(out)]) == 0
    assert payload in json.dumps(_page_data(out))
    _check_hostile_page(out, payload)


def test_explore_refuses_before_any_run(study_dir, tmp_path, capsys):
    cases = [
        (["front", "explore", str(study_dir / "out"), "--out", str(tmp_path / "p.txt")], "name it FILE.html"),
        (["front", "explore", str(study_dir / "out"), "--out", str(tmp_path / "p.html"), "--members", "0"],
         "--members"),
        (["front", "explore", str(study_dir / "out" / "agsta"), str(tmp_path / "none"), "--out",
          str(tmp_path / "p.html")], "none"),
    ]
    for argv, msg in cases:
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("arvcas: error: ") and msg in err and err.count("\n") == 1, err
        assert not (tmp_path / "p.html").exists()


def test_no_output_for_the_bluerov2_names_a_paper_table(study_dir, page, tmp_path, capsys):
    """Every text a command prints or writes for the BlueROV2 (tables, reports, figures as SVG, the page's
    data, the front's dataset descriptions) names its own defaults and normalisation, never the paper's."""
    import h5py

    out, d = study_dir / "out", tmp_path
    runs = [
        ["compare", str(out / "agsta"), str(out / "proposed"), "--plot", str(d / "cmp.svg")],
        ["front", "plot", str(out / "proposed"), "--out", str(d / "front.svg")],
        ["front", "export", str(out / "proposed"), "--format", "json", "--out", str(d / "front.json")],
        ["front", "export", str(out / "proposed"), "--format", "csv"],
        ["front", "export", str(out / "proposed"), "--format", "mat", "--out", str(d / "front.mat")],
        ["knees", str(out), "--out", str(d / "knees"), "--format", "svg"],
        ["front", "robust", str(out / "agsta"), "--runs", "2", "--out", str(d / "robust"), "--format", "svg"],
        ["montecarlo", "--from-front", str(out / "proposed"), "--index", "knee", "--runs", "2", "--config",
         str(study_dir / "short.toml"), "--system", "bluerov2_heavy_alpha5", "--out", str(d / "mc.h5")],
        ["tune", str(study_dir / "study.toml"), "--out", str(out), "--resume"],
        ["sweep", "--system", "bluerov2_heavy_alpha5", "--config", str(study_dir / "short.toml"), "--h", "0.1",
         "--controllers", "proposed,agsta", "--out", str(d / "sweep"), "--format", "svg"],
    ]
    texts = []
    for argv in runs:
        assert cli.main(argv) == 0, argv
        texts.append(" ".join(capsys.readouterr()))
    for p in d.rglob("*"):
        if p.suffix in (".svg", ".md", ".json", ".csv", ".txt"):
            texts.append(p.read_text(encoding="utf-8"))
    assert (d / "cmp.svg").read_text().lstrip().startswith("<?xml") and "<svg" in (d / "knees" / "knees_thrust.svg").read_text()
    assert ">T8<" in (d / "knees" / "knees_thrust.svg").read_text()  # the system's own thruster names, as text
    texts.append(json.dumps(_page_data(page)))
    for h5 in [out / "proposed" / "front.h5", *d.rglob("*.h5")]:  # descriptions in the front and result files
        with h5py.File(h5, "r") as f:
            texts += [str(v) for v in f.attrs.values()]
            f.visititems(lambda n, o: texts.extend(str(v) for v in o.attrs.values()))
    from scipy.io import loadmat

    mat = loadmat(d / "front.mat", simplify_cells=True)
    texts += [str(mat[k]) for k in ("units", "description", "arvcas")]
    found = sorted({m.group(0) for t in texts for m in PAPER_NAMES.finditer(t)})
    assert not found, found
    joined = "\n".join(texts)
    assert "default gains" in joined and "AGSTA's value at the default gains" in joined


# ---- the front explorer on a study of three objectives (docs/objectives.md) ----------------------------------


@pytest.fixture(scope="module")
def page3(study_dir):
    """``study_dir``'s tiny study of the BlueROV2 on three objectives (NSGA-III, AGSTA alone) and its page."""
    d = study_dir / "three"
    d.mkdir()
    text = (study_dir / "study.toml").read_text(encoding="utf-8")
    for old, new in (('name = "b2tiny"', 'name = "b2three"'), ('["proposed", "agsta"]', '["agsta"]'),
                     ("seed = 5", "seed = 7"),
                     ("[algorithm]\npopulation = 6", '[algorithm]\nname = "nsga3"\npopulation = 12'),
                     ('names = ["chat", "rmse"]\nreference_point = [2.0, 2.0]',
                      'names = ["chat", "rmse", "energy"]\nreference_point = [2.0, 2.0, 1e6]\n'
                      'constraints = ["peak_thrust <= 0.17 * limit"]'),
                     ('scenario = "short.toml"', 'scenario = "../short.toml"')):
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    (d / "study.toml").write_text(text, encoding="utf-8")
    assert cli.main(["tune", str(d / "study.toml"), "--out", str(d / "out")]) == 0
    out = d / "front.html"
    assert cli.main(["front", "explore", str(d / "out"), "--out", str(out)]) == 0
    return d, out


def test_explore_page_of_three_objectives_holds_every_member_with_all_objectives(page3):
    from arvcas.tuning.front import read_front

    d, page = page3
    doc = _page_data(page)
    fr = read_front(d / "out")
    assert fr.objectives == ("chat", "rmse", "energy") and fr.size > 1
    assert [o["name"] for o in doc["objectives"]] == ["chat", "rmse", "energy"]
    assert doc["objectives"][2]["label"] == "f_energy (N^1.5 s)" and all(o["log"] for o in doc["objectives"])
    (f,) = doc["fronts"]
    assert f["F"] == fr.F.tolist() and all(len(p) == 3 for p in f["F"]) and f["knee"] == fr.knee()
    assert len(f["defaults"]["F"]) == 3 and f["defaults"]["F"] == fr.table2_F.tolist()
    assert sorted(f["traces"], key=str) == sorted([str(i) for i in range(fr.size)] + ["defaults"], key=str)
    assert f["replay"]["reproduced"]  # the replays (without the energy accumulator) give the stored CHAT and RMSE
    c = ck.read_checkpoint(d / "out" / "front.h5")  # the population drawn: its feasible rows (every constraint)
    feasible = (c.G <= 0).all(axis=1)
    assert 0 < feasible.sum() < len(feasible) and f["population"] == c.F[feasible].tolist()


@pytest.mark.parametrize("view", ["", "#x=energy&y=chat"])
def test_explore_page_of_three_objectives_loads_in_headless_chromium(page3, tmp_path, view):
    _, page = page3
    shot = tmp_path / "shot.png"
    dom, err = _chromium(["--window-size=1280,1100", f"--screenshot={shot}", "--dump-dom", page.as_uri() + view])
    assert not page_faults(dom, err)
    assert f'data-axes="{"energy,chat" if view else "chat,rmse"}"' in dom  # the axes drawn
    assert dom.count("<option") == 6 and 'id="axis-x"' in dom and 'id="axis-y"' in dom  # the two selectors
    from matplotlib.image import imread

    img = (imread(shot)[..., :3] * 255).round()
    f = _page_data(page)["fronts"][0]
    rgb = np.array([int(f["color"][k:k + 2], 16) for k in (1, 3, 5)], dtype=float)
    assert (np.abs(img[:600] - rgb).max(axis=2) <= 12).sum() > 100  # the front is drawn in its colour


def test_explore_axes_are_the_objectives_with_units_and_log_only_where_every_value_is_positive():
    from arvcas.experiments.explore import _objectives

    def front(F, pop, dflt):
        return {"F": F, "population": pop, "defaults": {"F": dflt}}

    fronts = [front([[0.5, 0.0], [1.0, 2.0]], [[2.0, 3.0]], [1.0, None]),
              front([[0.7, 1.0]], [[0.9, 4.0]], [None, None])]
    obj = _objectives(("chat", "saturation_time"), fronts, "the AGSTA's value")
    assert [o["label"] for o in obj] == ["f_chat (mean CHAT, normalised)", "f_saturation_time (s)"]
    assert [o["log"] for o in obj] == [True, False]  # a time in saturation of 0 s: a linear axis
    assert "the AGSTA's value" in obj[0]["description"] and obj[1]["unit"] == "s"
    fronts[1]["defaults"]["F"][0] = -1.0  # a negative value anywhere on the plot: linear as well
    assert [o["log"] for o in _objectives(("chat", "energy"), fronts, "n")] == [False, False]


def test_explore_refuses_fronts_of_different_objectives(study_dir, page3, tmp_path, capsys):
    d, _ = page3
    out = tmp_path / "p.html"
    assert cli.main(["front", "explore", str(study_dir / "out" / "agsta"), str(d / "out"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("arvcas: error: front explore: the fronts have different objectives (chat, rmse in ") \
        and "; chat, rmse, energy in " in err and err.count("\n") == 1, err
    assert not out.exists()
