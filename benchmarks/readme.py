"""Render every templated page of the repository: every number on it comes from a committed data file.

A page's template sits beside it: ``docs/README.in.md`` renders to ``README.md``, and every
``results/**/NAME.in.md`` to ``results/**/NAME.md``. The rendered page starts with a one-line HTML comment
naming its template and this command. A template is the page's text with placeholders:

``{{FILE:PATH*K|SPEC}}``
    one value of a committed file, ``FILE`` relative to the repository's root. For a JSON or TOML file
    ``PATH`` is a path of keys joined by ``/`` (keys such as ``plain_rk4_h_plant_0.0025`` hold dots; an
    integer indexes a list). For an HDF5 file (``.h5``) ``PATH`` is an object's path, ``/group/dataset``, or
    an attribute, ``/group@name`` (``/@name`` for the file's root); either may end in a NumPy index,
    ``[3]``, ``[-1]``, ``[0,2]``. For a CSV file (``arvcas front export``) ``PATH`` names a column, or several
    with ``*`` (``chat.*``: rows x columns). ``*K`` scales a number, ``SPEC`` is a Python format spec (``,.0f``,
    ``.2f``; none: the value as it is; ``.1e`` writes the exponent without padding, ``3.8e-8``).
``{{let NAME = FILE:PATH}}``, on a line of its own
    binds ``NAME`` to that value (a whole array when ``PATH`` names one); the line is not rendered.
    ``{{let NAME = FILE:re:REGEX}}`` binds the numbers of every match of ``REGEX`` (its groups, or the whole
    match; one number, or an array of matches x groups) in a committed text file that arvcas wrote (an
    ``arvcas compare`` report), and
    ``{{let NAME = EXPR}}`` the value of an expression.
``{{= EXPR|SPEC}}``
    the value of an expression over bound names: numbers, ``+ - * / // % **``, comparisons, indexing (NumPy's,
    a mask too: ``k1[t <= 30]``) and the functions ``min max mean median sum abs sqrt log exp len count all
    any argmin argmax round sort diff`` (``min(a, 0)``, ``sort(a)``, ``diff(a)``: along axis 0; ``min(a, b)``:
    of two numbers). Nothing else is evaluated.

A value measured on a tree with uncommitted changes (a section of ``results/bench.json`` whose
``git_commit`` ends in ``+dirty``) is refused: no page quotes what the repository cannot reproduce.

    python benchmarks/readme.py            # rewrite every rendered page (and the generated pages of results/)
    python benchmarks/readme.py --check    # exit 1 naming each page that differs from its rendering
"""

from __future__ import annotations

import argparse
import ast
import json
import operator
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEMPLATE = ROOT / "docs" / "README.in.md"
README = ROOT / "README.md"
COMMAND = "python benchmarks/readme.py"


def header(template: str) -> str:
    """The first line of the page rendered from ``template`` (a path relative to the repository's root)."""
    return (f"<!-- Rendered from {template} by `{COMMAND}`: edit that file. "
            "Every number comes from the committed data file named in its placeholder there. -->\n")


HEADER = header("docs/README.in.md")
_REF = r"([^:{}\s]+):([^|{}*\s]+)"
_PLACE = re.compile(r"\{\{\s*" + _REF + r"(?:\*([0-9.eE+-]+))?(?:\|([^{}]*))?\s*\}\}")
_LET = re.compile(r"^[ \t]*\{\{\s*let\s+([A-Za-z_]\w*)\s*=\s*(.*?)\s*\}\}[ \t]*\n", re.M)
_EXPR = re.compile(r"\{\{=\s*(.*?)\s*(?:\|([^{}|]*))?\}\}")
_TEXT = re.compile(r"([^:{}\s]+):re:(.+)")


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


def _index(x, text: str, where: str):
    """``x[...]`` for the NumPy index ``text`` (integers, slices, commas)."""
    import numpy as np
    try:
        parts = tuple(slice(*[int(p) if p.strip() else None for p in s.split(":")]) if ":" in s else int(s)
                      for s in text.split(","))
        return np.asarray(x)[parts if len(parts) > 1 else parts[0]]
    except (ValueError, IndexError, TypeError) as e:
        raise RenderError(f"{where}: index [{text}] does not apply ({e})") from None


def _h5_value(f: Path, file: str, path: str):
    """The HDF5 object or attribute at ``path`` (``/a/b``, ``/a@name``, optionally indexed) in ``f``."""
    import h5py
    import numpy as np
    where = f"{{{{{file}:{path}}}}}"
    m = re.fullmatch(r"(/[^@\[]*)(?:@([^\[]+))?(?:\[([^\]]+)\])?", path)
    if not m:
        raise RenderError(f"{where}: an HDF5 path is /group/dataset or /group@attribute, optionally [index]")
    obj, attr, idx = m.group(1), m.group(2), m.group(3)
    with h5py.File(f, "r") as h:
        if obj not in h:
            raise RenderError(f"{where}: no object {obj} in {file}")
        if attr is not None:
            if attr not in h[obj].attrs:
                raise RenderError(f"{where}: no attribute {attr!r} of {obj} in {file}")
            x = h[obj].attrs[attr]
        else:
            if not isinstance(h[obj], h5py.Dataset):
                raise RenderError(f"{where}: {obj} in {file} is a group, not a dataset (an attribute is {obj}@name)")
            x = h[obj][()]
    if idx is not None:
        x = _index(x, idx, where)
    if isinstance(x, bytes):
        x = x.decode()
    return x.item() if isinstance(x, np.generic) or (isinstance(x, np.ndarray) and x.ndim == 0) else x


def _text_value(root: Path, file: str, pattern: str):
    """The numbers of every match of ``pattern`` in the text file ``file`` (its groups, or the whole match): a
    number for one match of one group, else an array of matches x groups, squeezed."""
    import numpy as np
    where = f"{{{{{file}:re:{pattern}}}}}"
    f = root / file
    if not f.is_file():
        raise RenderError(f"{where}: no file {file}")
    try:
        found = list(re.finditer(pattern, f.read_text(), flags=re.M))
    except re.error as e:
        raise RenderError(f"{where}: not a regular expression ({e})") from None
    if not found:
        raise RenderError(f"{where}: no match in {file}")
    def number(g: str) -> float:  # "1,234" and "50%" as numbers, "-" and "n/a" (a table's empty cell) as NaN
        return float("nan") if g in ("-", "n/a") else float(g.replace(",", "").rstrip("%"))
    try:
        vals = [[number(g) for g in (m.groups() or (m.group(0),))] for m in found]
    except (AttributeError, ValueError):
        raise RenderError(f"{where}: matched {found[0].group(0)!r}, not numbers") from None
    a = np.squeeze(np.asarray(vals))
    return a.item() if a.ndim == 0 else a


def _csv_value(f: Path, file: str, path: str):
    """The column ``path`` of the CSV file ``f`` (``True``/``False`` as booleans, else numbers), or, for a
    pattern with ``*`` (``chat.*``), every matching column in the file's order: rows x columns."""
    import csv
    import fnmatch

    import numpy as np
    with open(f, newline="") as fh:
        rows = list(csv.reader(fh))
    cols = [i for i, name in enumerate(rows[0]) if fnmatch.fnmatchcase(name, path)]
    if not cols:
        raise RenderError(f"{{{{{file}:{path}}}}}: no column {path!r} in {file}")

    def cell(text: str):
        if text in ("True", "False"):
            return text == "True"
        return float(text) if text else float("nan")
    try:
        a = np.array([[cell(r[i]) for i in cols] for r in rows[1:]])
    except ValueError as e:
        raise RenderError(f"{{{{{file}:{path}}}}}: not numbers ({e})") from None
    return a[:, 0] if "*" not in path else a


def value(root: Path, file: str, path: str):
    """The value at ``path`` in the committed file ``file`` below ``root``: keys joined by ``/`` in a JSON
    file, an object or attribute path in an HDF5 file."""
    f = root / file
    if not f.is_file():
        raise RenderError(f"{{{{{file}:{path}}}}}: no file {file}")
    if f.suffix == ".h5":
        return _h5_value(f, file, path)
    if f.suffix == ".csv":
        return _csv_value(f, file, path)
    if f.suffix == ".toml":
        import tomllib
        doc = tomllib.loads(f.read_text())
    else:
        doc = json.loads(f.read_text())
    keys = path.split("/")
    if f.name == "bench.json":
        dirty = _dirty_section(doc, keys)
        if dirty:
            raise RenderError(f"{{{{{file}:{path}}}}}: measured on a tree with uncommitted changes ({dirty}); "
                              f"re-measure it at a clean commit")
    x = doc
    for k in keys:
        if isinstance(x, list) and re.fullmatch(r"-?\d+", k) and -len(x) <= int(k) < len(x):
            x = x[int(k)]
        elif isinstance(x, dict) and k in x:
            x = x[k]
        else:
            raise RenderError(f"{{{{{file}:{path}}}}}: no key {k!r} in {file}")
    return x


# ---- expressions ------------------------------------------------------------------------------------------

def _functions():
    import numpy as np

    def _reduce(fn):
        def f(a, b=None):
            if b is None:
                return fn(np.asarray(a))
            if np.ndim(b) == 0 and np.issubdtype(type(b), np.integer) and np.ndim(a) > 0:
                return fn(np.asarray(a), axis=int(b))
            return fn(np.asarray([a, b]), axis=0)
        return f
    return {"min": _reduce(np.min), "max": _reduce(np.max), "mean": _reduce(np.mean), "sum": _reduce(np.sum),
            "median": _reduce(np.median), "sort": lambda a: np.sort(np.asarray(a), axis=0),
            "abs": np.abs, "sqrt": np.sqrt, "len": len, "count": lambda a: int(np.count_nonzero(a)),
            "all": _reduce(np.all), "any": _reduce(np.any), "argmin": np.argmin,
            "argmax": np.argmax, "round": np.round, "log": np.log, "exp": np.exp, "diff": lambda a: np.diff(np.asarray(a), axis=0)}


_BIN = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
        ast.Pow: operator.pow, ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod, ast.BitAnd: operator.and_, ast.BitOr: operator.or_}
_CMP = {ast.Lt: operator.lt, ast.LtE: operator.le, ast.Gt: operator.gt, ast.GtE: operator.ge,
        ast.Eq: operator.eq, ast.NotEq: operator.ne}


def evaluate(expr: str, names: dict):
    """The value of ``expr`` over ``names``: arithmetic, comparisons, indexing and a few reductions only."""
    import numpy as np
    fns = _functions()
    try:
        tree = ast.parse(expr, mode="eval").body
    except SyntaxError:
        raise RenderError(f"{{{{= {expr}}}}}: not an expression") from None

    def ev(n):
        if isinstance(n, ast.Constant) and isinstance(n.value, (int, float)):
            return n.value
        if isinstance(n, ast.Name):
            if n.id not in names:
                raise RenderError(f"{{{{= {expr}}}}}: {n.id!r} is not bound by a {{{{let {n.id} = ...}}}} line")
            return names[n.id]
        if isinstance(n, ast.BinOp) and type(n.op) in _BIN:
            a, b = (ev(n.left), ev(n.right))
            return _BIN[type(n.op)](np.asarray(a) if isinstance(a, list) else a,
                                    np.asarray(b) if isinstance(b, list) else b)
        if isinstance(n, ast.UnaryOp) and isinstance(n.op, (ast.USub, ast.UAdd)):
            v = ev(n.operand)
            v = np.asarray(v) if isinstance(v, list) else v
            return -v if isinstance(n.op, ast.USub) else v
        if isinstance(n, ast.Compare) and len(n.ops) == 1 and type(n.ops[0]) in _CMP:
            return _CMP[type(n.ops[0])](np.asarray(ev(n.left)), np.asarray(ev(n.comparators[0])))
        if isinstance(n, ast.Subscript):
            return np.asarray(ev(n.value))[ev_index(n.slice)]
        if isinstance(n, (ast.Tuple, ast.List)):
            return [ev(e) for e in n.elts]
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id in fns and not n.keywords:
            return fns[n.func.id](*[ev(a) for a in n.args])
        raise RenderError(f"{{{{= {expr}}}}}: {ast.unparse(n)!r} is not allowed (arithmetic, comparisons, "
                          f"indexing and {', '.join(fns)} only)")

    def ev_index(n):
        if isinstance(n, ast.Slice):
            return slice(*(None if p is None else int(ev(p)) for p in (n.lower, n.upper, n.step)))
        if isinstance(n, ast.Tuple):
            return tuple(ev_index(e) for e in n.elts)
        v = ev(n)
        v = np.asarray(v) if isinstance(v, list) else v
        return v if isinstance(v, np.ndarray) else int(v)

    try:
        out = ev(tree)
    except RenderError:
        raise
    except (TypeError, ValueError, IndexError, ZeroDivisionError) as e:
        raise RenderError(f"{{{{= {expr}}}}}: {e}") from None
    return out.item() if isinstance(out, np.ndarray) and out.ndim == 0 else out


def _format(x, spec: str, where: str) -> str:
    import numpy as np
    if isinstance(x, np.generic):
        x = x.item()
    compact = spec.endswith("e") and not spec.endswith("ee")
    try:
        out = format(x, spec)
    except (TypeError, ValueError) as e:
        raise RenderError(f"{where}: format {spec!r} does not apply to {x!r} ({e})") from None
    return re.sub(r"e([+-])0*(\d)", lambda m: "e" + ("-" if m.group(1) == "-" else "") + m.group(2), out) \
        if compact else out


def render(template: str, root: Path = ROOT, source: str = "docs/README.in.md") -> str:
    """The page's text: its header naming ``source`` (the template), then :func:`body`."""
    return header(source) + body(template, root)


def body(template: str, root: Path = ROOT) -> str:
    """``template`` with every placeholder replaced by its value and every ``let`` line removed."""
    names: dict = {}

    def let(m: re.Match) -> str:
        name, rhs = m.group(1), m.group(2)
        t = _TEXT.fullmatch(rhs)
        r = re.fullmatch(r"([^:{}\s]+):(.+)", rhs)  # a key may hold spaces here ("proposed default")
        if t:
            names[name] = _text_value(root, t.group(1), t.group(2))
        elif r and re.search(r"\.(json|toml|h5|csv)$", r.group(1)):
            names[name] = value(root, r.group(1), r.group(2))
        else:
            names[name] = evaluate(rhs, names)
        return ""

    def one(m: re.Match) -> str:
        file, path, scale, spec = m.group(1), m.group(2), m.group(3), (m.group(4) or "").strip()
        x = value(root, file, path)
        if scale is not None:
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise RenderError(f"{m.group(0)}: a scale needs a number, the file holds {x!r}")
            x = x * float(scale)
        return _format(x, spec, m.group(0))

    def expr(m: re.Match) -> str:
        return _format(evaluate(m.group(1), names), (m.group(2) or "").strip(), m.group(0))

    out = _LET.sub(let, template)
    out = _EXPR.sub(expr, out)
    out = _PLACE.sub(one, out)
    left = re.search(r"\{\{[^}]*\}\}", out)
    if left:
        raise RenderError(f"{left.group(0)}: not a placeholder of the form {{{{FILE:PATH|SPEC}}}}, "
                          f"{{{{= EXPR|SPEC}}}} or a {{{{let NAME = ...}}}} line")
    return out


# ---- the pages --------------------------------------------------------------------------------------------

def pages(root: Path = ROOT) -> dict[str, str]:
    """Every rendered page and its template, paths relative to ``root``: README.md and results/**/X.md."""
    out = {"README.md": "docs/README.in.md"}
    for t in sorted((root / "results").rglob("*.in.md")):
        rel = t.relative_to(root).as_posix()
        out[rel[:-len(".in.md")] + ".md"] = rel
    return out


def rendered(root: Path = ROOT) -> dict[str, str]:
    """Every templated page's text as rendered from its template and the committed data."""
    return {page: render((root / src).read_text(), root, src) for page, src in pages(root).items()}


def stale(root: Path = ROOT) -> list[str]:
    """The pages that differ from their rendering: templated pages, then the generated pages of results/."""
    out = [p for p, text in rendered(root).items()
           if not (root / p).is_file() or (root / p).read_text() != text]
    if root == ROOT:
        sys.path.insert(0, str(ROOT / "benchmarks"))
        try:
            import render_results
        finally:
            sys.path.pop(0)
        out += [p for p, text in render_results.rendered(root).items() if (root / p).read_text() != text]
    return out


def write(root: Path = ROOT) -> list[str]:
    """Rewrite every templated page; a page that exists and was not rendered from its template (its first
    line is not the header naming it) is refused, not replaced."""
    texts = rendered(root)
    src = pages(root)
    for page in texts:
        f = root / page
        if f.is_file() and f.read_text().split("\n", 1)[0] + "\n" != header(src[page]):
            raise RenderError(f"{page}: not rendered from {src[page]} (its first line is not the header naming "
                              f"it); move it aside to render it")
    for page, text in texts.items():
        (root / page).write_text(text)
    return list(texts)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="render README.md and results/**/*.md from their templates "
                                             "(X.in.md beside each) and the committed data")
    ap.add_argument("--check", action="store_true",
                    help="write nothing; exit 1 naming each page that differs from its rendering")
    a = ap.parse_args(argv)
    try:
        if a.check:
            bad = stale()
            if bad:
                print(f"readme: differ from their rendering (run {COMMAND}): " + ", ".join(bad), file=sys.stderr)
                return 1
            return 0
        write()
    except RenderError as e:
        print(f"readme: error: {e}", file=sys.stderr)
        return 2
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import render_results
    return render_results.main([])


if __name__ == "__main__":
    sys.exit(main())
