"""The README tells the truth: its numbers are rendered from committed data, and its code blocks run as written.

- README.md equals the rendering of docs/README.in.md by benchmarks/readme.py (every number from a committed
  data file; nothing measured on a tree with uncommitted changes);
- the renderer refuses what it cannot vouch for (a missing key, a value measured on a dirty tree);
- every ```python block of the README runs as written, and every ```bash block too, in a copy of the shipped
  results and studies, less the two steps CI's own script is made of (installing the package, running this suite).
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _renderer():
    spec = importlib.util.spec_from_file_location("arvcas_readme_renderer", ROOT / "benchmarks" / "readme.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", (ROOT / "README.md").read_text(), flags=re.S | re.M)


def test_readme_is_its_rendering():
    r = _renderer()
    assert (ROOT / "README.md").read_text() == r.render(r.TEMPLATE.read_text()), \
        "README.md differs from docs/README.in.md rendered: run python benchmarks/readme.py"


def test_readme_is_short_and_has_no_machine_paths():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    assert not re.search(r"(/work/|/home/|/tmp/|/root/|[A-Z]:\\\\)", text)
    assert not re.search(r"\b[Ii]ssues? \d+", text)


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

