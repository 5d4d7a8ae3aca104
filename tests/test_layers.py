"""The package's layers (docs/architecture.md): no import circle between arvcas modules, and no layer
importing one above it. Imports inside functions count as well as those at the top of a module.

The import graph is read from the source with ``ast`` (nothing is imported): ``import arvcas.x.y`` and
``from arvcas.x import y`` are edges to ``arvcas.x.y`` (a module, when it is one) or to the package
``arvcas.x``; relative imports are resolved. ``from arvcas import __version__`` is allowed everywhere (the
version is set before the package's ``__init__`` imports anything); any other import of the package root
``arvcas`` (the public facade) is an import of the top layer.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "arvcas"

# docs/architecture.md's table, lowest first: a module may import its own layer and those before it.
LAYERS = (
    ("files", ("arvcas.io.files",)),  # atomic writes, locks, bounded reads: used by every layer that touches a file
    ("plugins", ("arvcas.io.plugins",)),  # code from outside the package: used by every registry
    ("parameters and systems", ("arvcas.system",)),
    ("models", ("arvcas.model",)),
    ("build", ("arvcas.build",)),
    ("controllers", ("arvcas.controllers",)),
    ("simulation", ("arvcas.sim",)),
    ("metrics", ("arvcas.metrics",)),
    ("I/O", ("arvcas.io",)),
    ("tuning", ("arvcas.tuning",)),
    ("logs, validation and identification", ("arvcas.ident",)),
    ("experiments", ("arvcas.experiments",)),
    ("command line and the public facade", ("arvcas.cli", "arvcas")),
    ("benchmark", ("arvcas.bench",)),  # arvcas bench: measures every layer, runs the command line
)

# Deliberate imports against the order, each inside a function (checked below), with the reason.
ALLOWED_UPWARD = {
    ("arvcas.system.params", "arvcas.model.manipulator"): "the physical check evaluates the model's own matrices",
    ("arvcas.system.params", "arvcas.model.thrusters"): "the physical check evaluates the model's own matrices",
    ("arvcas.system.params", "arvcas.model.vehicle"): "the physical check evaluates the model's own matrices",
    ("arvcas.build.fmu", "arvcas.sim.scenario"): "an FMU's start values are the system's default scenario's",
    ("arvcas.controllers.base", "arvcas.sim.signals"): "a registered law's signals are checked against the one "
                                                       "signal table (sim/signals.py imports nothing of arvcas)",
}
# Imports against the order at a module's top: controllers declare their traced signals with the run's
# one signal table, sim/signals.py, a leaf module (it imports nothing of arvcas).
ALLOWED_UPWARD_TOP = {
    ("arvcas.controllers.pid", "arvcas.sim.signals"),
    ("arvcas.controllers.smc", "arvcas.sim.signals"),
}

# Deliberate circles, each broken by one import inside a function (checked below), with the reason.
ALLOWED_CYCLE = {
    ("arvcas.sim.scenario", "arvcas.sim.schedule"): "a scenario file's load refuses a time table too large for "
                                                    "memory before any work; the table's record size is the schedule's",
}


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
                if mod == "arvcas" and [a.name for a in child.names] == ["__version__"]:
                    continue
                for a in child.names:
                    sub = f"{mod}.{a.name}"
                    out.append((sub if sub in MODULES else mod, child.lineno, in_function))
            visit(child, inner)

    visit(tree, False)
    return out


GRAPH = {m: _imports(m, p) for m, p in MODULES.items()}


def layer_of(module: str) -> int:
    best, level = -1, None
    for i, (_, prefixes) in enumerate(LAYERS):
        for pre in prefixes:
            if (module == pre or module.startswith(pre + ".")) and len(pre) > best:
                best, level = len(pre), i
    assert level is not None, f"{module}: in no layer of LAYERS (docs/architecture.md)"
    return level


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
    edges = {m: {t for t, _, lazy in imps if t != "arvcas" and t != m and not (lazy and (m, t) in ALLOWED_CYCLE)}
             for m, imps in GRAPH.items() if m != "arvcas"}
    assert _cycles(edges) == []


def test_layers_import_only_downward():
    bad = []
    for m, imps in sorted(GRAPH.items()):
        for t, line, lazy in imps:
            if layer_of(t) <= layer_of(m):
                continue
            if (m, t) in ALLOWED_UPWARD and lazy or (m, t) in ALLOWED_UPWARD_TOP:
                continue
            bad.append(f"{MODULES[m].relative_to(PKG.parent)}:{line}: {m} ({LAYERS[layer_of(m)][0]}) imports "
                       f"{t} ({LAYERS[layer_of(t)][0]})" + (" inside a function" if lazy else ""))
    assert not bad, "imports from a higher layer:\n" + "\n".join(bad)


@pytest.mark.parametrize("edge", sorted(ALLOWED_UPWARD) + sorted(ALLOWED_UPWARD_TOP) + sorted(ALLOWED_CYCLE))
def test_allowed_exceptions_are_live(edge):
    """Each listed exception is still in the code (a stale entry would silently allow a new one)."""
    m, t = edge
    lazy = {lz for tt, _, lz in GRAPH[m] if tt == t}
    assert lazy, f"{m} no longer imports {t}: remove it from the exceptions"
    if edge not in ALLOWED_UPWARD_TOP:
        assert lazy == {True}, f"{m} imports {t} at its top: only an import inside a function is allowed"
