"""The package's layers (docs/architecture.md).

The layers themselves are import-linter's layers contract in pyproject.toml (``lint-imports`` at the
repository's root runs it; the imports against the order are its ``ignore_imports``, each with its reason).
What that contract cannot say is checked here from the source, read with ``ast`` (nothing is imported):
no import circle between modules of one layer, every module in a layer of the contract, and each exception
made inside a function (an import at a module's top would load the higher layer with the lower one).
Imports inside functions count as well as those at the top of a module. ``import arvcas.x.y`` and
``from arvcas.x import y`` are edges to ``arvcas.x.y`` (a module, when it is one) or to the package
``arvcas.x``; relative imports are resolved.
"""

from __future__ import annotations

import ast
import fnmatch
import tomllib
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "arvcas"

ROOT = PKG.parent
CONTRACT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["importlinter"]
LAYERS = [name.strip() for layer in CONTRACT["contracts"][0]["layers"] for name in layer.split(":")]
# exceptions that may stand at a module's top: the controllers declare their traced signals with the run's
# one signal table, sim/signals.py, a leaf module (it imports nothing of arvcas)
TOP_LEVEL_EXCEPTIONS = {"arvcas.sim.signals"}

def _modules() -> dict[str, Path]:
    out = {}
    for f in PKG.rglob("*.py"):
        parts = list(f.relative_to(PKG.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = f
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> list[tuple[str, int, bool]]:
    """(imported arvcas module or package, line, inside a function) of every import in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []

    def visit(node, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                out.extend((a.name, child.lineno, in_function) for a in child.names if a.name.split(".")[0] == "arvcas")
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = pkg.split(".")[: len(pkg.split(".")) - child.level + 1]
                    mod = ".".join(base + ([child.module] if child.module else []))
                else:
                    mod = child.module or ""
                if mod.split(".")[0] != "arvcas":
                    continue
                for a in child.names:
                    sub = f"{mod}.{a.name}"
                    out.append((sub if sub in MODULES else mod, child.lineno, in_function))
            visit(child, inner)

    visit(tree, False)
    return out


GRAPH = {m: _imports(m, p) for m, p in MODULES.items()}


def layer_of(module: str) -> str | None:
    """The contract's layer that holds ``module`` (the longest name that is it or a package above it)."""
    held = [name for name in LAYERS if module == name or module.startswith(name + ".")]
    return max(held, key=len, default=None)


def _ignored() -> list[tuple[str, str]]:
    """(importer pattern, imported) of each of the contract's ``ignore_imports``."""
    return [tuple(part.strip() for part in rule.split("->")) for rule in CONTRACT["contracts"][0]["ignore_imports"]]


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on, comps, n = {}, {}, [], set(), [], [0]

    def connect(v):
        index[v] = low[v] = n[0]
        n[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1 or v in edges.get(v, ()):
                comps.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            connect(v)
    return comps


def test_graph_is_read():
    """The reader finds the modules and their imports (a broken reader would pass every check below)."""
    assert len(MODULES) > 60 and "arvcas.system.params" in MODULES and "arvcas.io.cliargs" in MODULES
    assert ("arvcas.sim.closedloop", "arvcas.controllers.base") in {(m, t) for m in GRAPH for t, _, _ in GRAPH[m]}
    assert any(t == "arvcas.model.vehicle" and lazy for t, _, lazy in GRAPH["arvcas.system.params"])
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycles():
    """No circle between arvcas modules, counting imports inside functions (the package root, which
    re-exports the public API, is left out: importing any submodule runs it first)."""
    edges = {m: {t for t, _, lazy in imps if t != "arvcas" and t != m}
             for m, imps in GRAPH.items() if m != "arvcas"}
    assert _cycles(edges) == []


def test_layers_contract(capsys):
    """import-linter's layers contract (pyproject.toml) holds: no module imports a layer above its own,
    except the listed ``ignore_imports`` (an entry that no longer matches an import fails too)."""
    from importlinter.cli import lint_imports

    code = lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True, no_logo=True)
    assert code == 0, capsys.readouterr().out


def test_every_module_is_in_a_layer():
    """A module that no layer of the contract holds would be checked by nothing (the I/O layer names its
    modules one by one, since files and plugins are the ground floor)."""
    # the package root (the public facade, above every layer), its version (a leaf, below every layer) and
    # the docstring-only __init__ of the I/O package and of the ground floor (util)
    outside = ("arvcas", "arvcas._version", "arvcas.io", "arvcas.util")
    assert [m for m in MODULES if m not in outside and layer_of(m) is None] == []


def test_exceptions_are_made_inside_a_function():
    """Each import against the order that the contract ignores is made inside a function (the signal
    table, a leaf module, excepted), so the higher layer is not loaded with the lower one."""
    top = []
    for pattern, target in _ignored():
        for m in MODULES:
            if fnmatch.fnmatchcase(m, pattern):
                top += [f"{m}:{line} imports {t} at its top" for t, line, lazy in GRAPH[m]
                        if t == target and not lazy and t not in TOP_LEVEL_EXCEPTIONS]
    assert top == []


MAX_MODULE_LINES = 900  # a module a reader can hold: split by what it does before it grows past this


def test_no_module_over_900_lines():
    """No module of the package or of benchmarks/ is longer than :data:`MAX_MODULE_LINES` lines."""
    files = [*PKG.rglob("*.py"), *(ROOT / "benchmarks").rglob("*.py")]
    assert len(files) > 60
    long = {str(f.relative_to(ROOT)): n for f in files
            if (n := len(f.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES}
    assert long == {}
