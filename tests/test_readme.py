"""The README and the results' pages tell the truth: their numbers are rendered from committed data, and the
README's code blocks run as written.

- README.md equals the rendering of docs/README.in.md by benchmarks/readme.py, and every results/**/X.md with a
  template X.in.md beside it equals its rendering (every number from a committed data file; nothing measured on
  a tree with uncommitted changes); `readme.py --check` also covers the generated pages of render_results.py;
- the renderer reads JSON, TOML, HDF5 (datasets, attributes, indices) and arvcas's text reports, evaluates only
  its small expression language, and refuses what it cannot vouch for (a missing key, a value measured on a
  dirty tree, a page it did not render);
- every ```python block of the README runs as written, and every ```bash block too, in a copy of the shipped
  results and studies, less the two steps CI's own script is made of (installing the package, running this suite).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from script_helpers import load_script

ROOT = Path(__file__).resolve().parents[1]


def _renderer():
    return load_script("benchmarks/readme.py", "arvcas_readme_renderer")


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", (ROOT / "README.md").read_text(), flags=re.S | re.M)


def test_readme_is_its_rendering():
    r = _renderer()
    assert (ROOT / "README.md").read_text() == r.render(r.TEMPLATE.read_text()), \
        "README.md differs from docs/README.in.md rendered: run python benchmarks/readme.py"


def test_every_page_is_its_rendering():
    """One check for every page: README.md, each templated results page and render_results.py's pages."""
    r = _renderer()
    assert len(r.pages()) > 1, "no results page has a template"
    assert r.stale() == [], "differ from their rendering: run python benchmarks/readme.py"
    for page in r.pages():
        assert (ROOT / page).read_text().startswith(r.header(r.pages()[page]))


def test_readme_is_short_and_has_no_machine_paths():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    assert not re.search(r"\b[Ii]ssues? \d+", text)
    for f in [ROOT / "README.md", *(ROOT / "results").rglob("*.md"), *(ROOT / "docs").rglob("*.md")]:
        # /home/me/: the docs' example of a user's plugin file, not a path of the machine that wrote them
        assert not re.search(r"(/work/|/home/(?!me/)|/tmp/|/root/|[A-Z]:\\\\)", f.read_text()), f


def test_renderer_refuses_what_it_cannot_vouch_for(tmp_path):
    r = _renderer()
    (tmp_path / "results").mkdir()
    doc = {"machine": {"git_commit": "abc"}, "partial": {"lanes": {"git_commit": "def+dirty"}},
           "systems": {"a": {"x": 1234.5}}, "lanes": {"y": 2.0}}
    (tmp_path / "results" / "bench.json").write_text(json.dumps(doc))
    assert r.render("{{results/bench.json:systems/a/x|,.0f}} x", tmp_path) == r.HEADER + "1,234 x"
    assert r.render("{{results/bench.json:systems/a/x*0.001|.2f}}", tmp_path) == r.HEADER + "1.23"
    for bad, why in [("{{results/bench.json:lanes/y}}", "uncommitted changes"),
                     ("{{results/bench.json:systems/b}}", "no key 'b'"),
                     ("{{results/other.json:a}}", "no file"),
                     ("{{results/bench.json:systems/a/x|q}}", "format"),
                     ("{{ not a placeholder }}", "not a placeholder")]:
        with pytest.raises(r.RenderError, match=why):
            r.render(bad, tmp_path)


def _tree(tmp_path: Path) -> Path:
    """A small repository: an HDF5 result, a JSON, a text report and a results page's template."""
    import h5py
    import numpy as np
    (tmp_path / "results" / "x").mkdir(parents=True)
    with h5py.File(tmp_path / "results" / "x" / "run.h5", "w") as h:
        h.attrs["chat"] = np.array([3.0, 6.0, 1.5])
        h["t"] = np.arange(5) * 0.5
        h.create_group("front")["F"] = np.array([[1.0, 2.0], [3.0, 4.0]])
        h["front"].attrs["n"] = 2
    (tmp_path / "results" / "x" / "m.json").write_text(json.dumps({"a": {"b": 0.000123}}))
    (tmp_path / "results" / "x" / "compare.txt").write_text("agsta   79   750.557\nproposed   69   779.59\n")
    (tmp_path / "results" / "x" / "front.csv").write_text("member,knee,chat.x,chat.y\n0,False,1.5,2.5\n"
                                                         "4,True,0.5,3.5\n")
    (tmp_path / "results" / "x" / "README.in.md").write_text(
        "# X\n{{let c = results/x/run.h5:/@chat}}\n"
        "{{let hv = results/x/compare.txt:re:^\\w+\\s+(\\d+)\\s+(\\S+)$}}\n"
        "{{let knee = results/x/front.csv:knee}}\n{{let chat = results/x/front.csv:chat.*}}\n"
        "ratio {{= c[0] / c[1]|.2f}}, {{= count(c > 2)}} of {{= len(c)}}, F {{results/x/run.h5:/front/F[1,0]|.1f}}, "
        "n {{results/x/run.h5:/front@n}}, last t {{results/x/run.h5:/t[-1]}}, {{results/x/m.json:a/b|.1e}}, "
        "HV {{= hv[1, 1]|.2f}} ({{= hv[0, 0]|.0f}} members), late {{= max(c[1:])|.1f}}, "
        "knee {{= chat[argmax(knee), 1]}}\n")
    return tmp_path


def test_results_page_renders_every_source(tmp_path):
    r = _renderer()
    root = _tree(tmp_path)
    assert r.pages(root) == {"README.md": "docs/README.in.md", "results/x/README.md": "results/x/README.in.md"}
    src = "results/x/README.in.md"
    text = r.render((root / src).read_text(), root, src)
    assert text == (r.header(src) + "# X\nratio 0.50, 2 of 3, F 3.0, n 2, last t 2.0, 1.2e-4, HV 779.59 (79 members), "
                    "late 6.0, knee 3.5\n")
    assert text.startswith("<!-- Rendered from results/x/README.in.md by `python benchmarks/readme.py`")


def test_check_fails_on_a_page_edited_by_hand(tmp_path):
    r = _renderer()
    root = _tree(tmp_path)
    (root / "docs").mkdir()
    (root / "docs" / "README.in.md").write_text("top\n")
    (root / "results" / "x" / "README.md").write_text("# X\nhand-written\n")
    with pytest.raises(r.RenderError, match="results/x/README.md: not rendered from results/x/README.in.md"):
        r.write(root)  # a page it did not render is not replaced
    (root / "results" / "x" / "README.md").unlink()
    assert r.write(root) == ["README.md", "results/x/README.md"]
    assert r.stale(root) == []
    page = root / "results" / "x" / "README.md"
    page.write_text(page.read_text().replace("ratio 0.50", "ratio 0.51"))
    assert r.stale(root) == ["results/x/README.md"]
    (root / "results" / "x" / "README.in.md").write_text("{{= c}}\n")
    with pytest.raises(r.RenderError, match="'c' is not bound"):
        r.rendered(root)


def test_check_command_names_each_page_that_differs(monkeypatch, capsys):
    """``readme.py --check``: exit 1 and one line naming the pages (here two made stale), exit 0 when none is."""
    r = _renderer()
    monkeypatch.setattr(r, "stale", lambda root=r.ROOT: ["results/x/README.md", "results/y.md"])
    assert r.main(["--check"]) == 1
    err = capsys.readouterr().err
    assert "results/x/README.md, results/y.md" in err and "python benchmarks/readme.py" in err
    monkeypatch.setattr(r, "stale", lambda root=r.ROOT: [])
    assert r.main(["--check"]) == 0


def test_expressions_evaluate_only_their_language(tmp_path):
    r = _renderer()
    root = _tree(tmp_path)
    for bad, why in [("{{= __import__('os')}}", "not allowed"),
                     ("{{= c.real}}", "not allowed"),
                     ("{{let c = results/x/run.h5:/@chat}}\n{{= c[7]}}", "index"),
                     ("{{results/x/run.h5:/front}}", "a group, not a dataset"),
                     ("{{results/x/run.h5:/@nope}}", "no attribute 'nope'"),
                     ("{{results/x/run.h5:/nope}}", "no object /nope"),
                     ("{{let h = results/x/compare.txt:re:^pid}}\n", "no match"),
                     ("{{= 1 +}}", "not an expression")]:
        with pytest.raises(r.RenderError, match=why):
            r.render(bad, root)
    assert r.render("{{= min(3, 2) * 10 ** -8|.1e}}", root) == r.HEADER + "2.0e-8"


def _env() -> dict:
    env = dict(os.environ)
    env["MPLBACKEND"] = "Agg"
    return env


@pytest.mark.slow
def test_readme_python_blocks_run(tmp_path):
    blocks = _blocks("python")
    assert blocks, "the README has no python block"
    for code in blocks:
        p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                           env=_env(), timeout=600)
        assert p.returncode == 0, p.stderr[-2000:]


def _commands(block: str) -> list[str]:
    """The block's commands, less installing the package and running this suite (what .ci/run does)."""
    out = []
    for line in block.splitlines():
        line = line.split("#", 1)[0].strip()
        for part in (s.strip() for s in line.split("&&")):
            if part and not part.startswith(("python -m pip install", "python -m pytest")):
                out.append(part)
    return out


@pytest.mark.slow
def test_readme_shell_blocks_run(tmp_path):
    """Run in a copy of the checkout's shipped results and studies, as a reader in the checkout would."""
    cmds = [c for b in _blocks("bash") for c in _commands(b)]
    assert cmds, "the README's shell blocks have no command to run"
    for d in ("results", "studies"):
        shutil.copytree(ROOT / d, tmp_path / d)
    bindir = Path(sys.executable).parent
    for c in cmds:
        argv = shlex.split(c)
        exe = bindir / argv[0]
        argv[0] = str(exe) if exe.exists() else argv[0]
        p = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, env=_env(), timeout=900)
        assert p.returncode == 0, f"{c}: {p.stderr[-2000:]}"

