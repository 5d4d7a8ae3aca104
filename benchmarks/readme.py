"""Render README.md from docs/README.in.md: every number in the README comes from a committed data file.

The template is the README's text with placeholders ``{{FILE:KEY/KEY/...|SPEC}}``: ``FILE`` a JSON file relative to
the repository's root, the keys a path into it (``/`` between keys, since keys such as
``plain_rk4_h_plant_0.0025`` hold dots), an optional scale ``*K`` after the path, and ``SPEC`` a Python format
spec (``,.0f``, ``.2f``; none: the value as it is). A value measured on a tree with uncommitted changes (a section of
``results/bench.json`` whose ``git_commit`` ends in ``+dirty``) is refused: the README quotes nothing that the
repository cannot reproduce.

    python benchmarks/readme.py            # rewrite README.md
    python benchmarks/readme.py --check    # exit 1 if README.md differs from its rendering (tests/test_readme.py)
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEMPLATE = ROOT / "docs" / "README.in.md"
README = ROOT / "README.md"
HEADER = ("<!-- Rendered from docs/README.in.md by `python benchmarks/readme.py`: edit that file. "
          "Every number comes from the committed data file named in its placeholder there. -->\n")
_PLACE = re.compile(r"\{\{\s*([^:{}\s]+):([^|{}*\s]+)(?:\*([0-9.eE+-]+))?(?:\|([^{}]*))?\s*\}\}")


class RenderError(ValueError):
    """A placeholder that cannot be rendered (one line: which placeholder and why)."""


def _dirty_section(doc: dict, keys: list[str]) -> str | None:
    """The commit of the section of ``results/bench.json`` that holds ``keys``, if it was a dirty tree."""
    partial = doc.get("partial", {})
    if keys and keys[0] in partial:
        commit = str(partial[keys[0]].get("git_commit", ""))
    else:
        commit = str(doc.get("machine", {}).get("git_commit", ""))
    return commit if commit.endswith("+dirty") else None


def value(root: Path, file: str, path: str):
    """The value at ``path`` (keys joined by ``/``) in the JSON file ``file`` below ``root``."""
    f = root / file
    if not f.is_file():
        raise RenderError(f"{{{{{file}:{path}}}}}: no file {file}")
    doc = json.loads(f.read_text())
    keys = path.split("/")
    if f.name == "bench.json":
        dirty = _dirty_section(doc, keys)
        if dirty:
            raise RenderError(f"{{{{{file}:{path}}}}}: measured on a tree with uncommitted changes ({dirty}); "
                              f"re-measure it at a clean commit")
    x = doc
    for k in keys:
        if not isinstance(x, dict) or k not in x:
            raise RenderError(f"{{{{{file}:{path}}}}}: no key {k!r} in {file}")
        x = x[k]
    return x


def render(template: str, root: Path = ROOT) -> str:
    """The README's text: every placeholder of ``template`` replaced by its formatted value."""
    def one(m: re.Match) -> str:
        file, path, scale, spec = m.group(1), m.group(2), m.group(3), (m.group(4) or "").strip()
        x = value(root, file, path)
        if scale is not None:
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise RenderError(f"{m.group(0)}: a scale needs a number, the file holds {x!r}")
            x = x * float(scale)
        try:
            return format(x, spec)
        except (TypeError, ValueError) as e:
            raise RenderError(f"{m.group(0)}: format {spec!r} does not apply to {x!r} ({e})") from None
    out = _PLACE.sub(one, template)
    left = re.search(r"\{\{[^}]*\}\}", out)
    if left:
        raise RenderError(f"{left.group(0)}: not a placeholder of the form {{{{FILE:KEY/KEY|SPEC}}}}")
    return HEADER + out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="render README.md from docs/README.in.md")
    ap.add_argument("--check", action="store_true", help="exit 1 if README.md differs from its rendering")
    a = ap.parse_args(argv)
    try:
        text = render(TEMPLATE.read_text())
    except RenderError as e:
        print(f"readme: error: {e}", file=sys.stderr)
        return 2
    if a.check:
        if README.read_text() != text:
            print("readme: README.md differs from its rendering of docs/README.in.md: "
                  "run python benchmarks/readme.py", file=sys.stderr)
            return 1
        return 0
    README.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
