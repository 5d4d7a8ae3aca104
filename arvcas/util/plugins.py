"""Code from outside the package: plugins found by entry points or named by the user, and where each
registered thing came from.

A plugin is a Python module that defines controllers or objectives (:mod:`arvcas.metrics.objectives`). It is found three ways:

* **entry points** of an installed distribution, in the groups of :data:`GROUPS`
  (``arvcas.controllers``, ``arvcas.objectives``), read with
  :func:`importlib.metadata.entry_points` as pytest and Optuna read theirs. They are loaded lazily: a
  registry asks for the entry points named like a name it does not hold (:func:`find`), and for all of
  them only when that name is still missing or when it lists what it offers (:func:`load_group`); a
  command that never asks never imports them, so a broken plugin never breaks it;
* **by name** (:func:`load`): a Python file (``my_law.py``, a path; relative to ``base_dir`` when one is
  given, e.g. the study file's directory) or an importable module (``mylab.control``): the command
  line's ``--plugin`` and a study file's ``[study] plugins``;
* a module the user's own Python code imported and registered from (no plugin record: the registry
  names the class's module and file).

A registry declares itself with :func:`add_registry` (group, ``adopt``): every object a plugin
yields (the module of a file or module plugin, the object an entry point names) is handed to the
``adopt`` of each registry, which registers what it recognises (:mod:`arvcas.controllers.base`: the
:class:`~arvcas.controllers.Controller` subclasses and instances a module defines). While a plugin's
code runs, :func:`current` is that plugin, so a registry can record where each entry came from even
when the module registers its entries itself.

A plugin that fails to import is one line (:class:`PluginError`) naming the file, module or entry
point and its distribution, and the error with its line in the plugin's code.

A file plugin is imported as the module named like the file (``my_law.py``: ``my_law``) unless that
name is taken by another module (loaded, or importable from ``sys.path``): then under a private name
(``arvcas_plugin_my_law_<hash of the path>``). The module's name is part of a controller's identity,
so the same file loaded as a file or as an installed module keys the same compiled libraries.

:func:`source_files` lists the files whose code defines a module (every ``.py`` file of its top-level
package, when it is in one): a law's compiled library is keyed by their contents, and a front records
their digest (:func:`digest`). This module imports nothing of arvcas but :mod:`arvcas.util.files`.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import importlib.util
import sys
import threading
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

__all__ = ["GROUPS", "PluginError", "Plugin", "add_registry", "load", "find", "load_group", "failures",
           "current", "loaded", "source_files", "digest", "is_file_spec", "why"]

GROUPS = ("arvcas.controllers", "arvcas.objectives")  # entry-point groups (arvcas.metrics.objectives: the second)


class PluginError(ValueError):
    """One line: which plugin (file, module or entry point and distribution) and what went wrong."""


@dataclass(frozen=True)
class Plugin:
    """Where code came from. ``kind``: "file", "module" or "entry point"; ``spec``: what ``--plugin``
    takes to load it again (the file's absolute path or the module name; for an entry point the module
    it names, which is found by itself when its distribution is installed); ``module``: its name in
    ``sys.modules``; ``entry_point`` ("group: name = value") and ``distribution`` ("name version") for
    an entry point."""

    kind: str
    spec: str
    module: str
    entry_point: str = ""
    distribution: str = ""

    def describe(self) -> str:
        if self.kind == "entry point":
            return f"entry point '{self.entry_point}'" + (f" of distribution {self.distribution}" if self.distribution else "")
        return f"plugin {self.kind} {self.spec}"

    def hint(self) -> str:
        """How to make it available again (one clause)."""
        if self.kind == "entry point":
            dist = self.distribution.split(" ")[0] if self.distribution else ""
            return (f"install the distribution {dist} that provides it" if dist else
                    f"install the distribution that provides it") + f", or load it with --plugin {self.spec}"
        return f"load it with --plugin {self.spec}"

    def record(self) -> dict:
        return {"kind": self.kind, "spec": self.spec, "module": self.module, "entry_point": self.entry_point,
                "distribution": self.distribution}


_LOCK = threading.RLock()  # one plugin loads at a time; a plugin may load another (re-entrant)
_ADOPT: dict[str, Callable[[object], list]] = {}  # group -> the registry's adopt(object) -> names registered
_LOADED: dict[str, tuple[Plugin, object]] = {}  # file path or module name -> (plugin, module)
_YIELDED: list[tuple[Plugin, object]] = []  # every object a plugin gave, for registries declared later
_EP_DONE: dict[str, set] = {}  # group -> entry points loaded (or failed), as "name = value"
_EP_ALL: set = set()  # groups whose entry points were all loaded
_FAILED: dict[str, dict[str, str]] = {}  # group -> entry point -> its one-line failure
_CURRENT: list[Plugin] = []


def current() -> Plugin | None:
    """The plugin whose code is running (its import or its registration), or None."""
    with _LOCK:
        return _CURRENT[-1] if _CURRENT else None


def loaded() -> list[Plugin]:
    """The plugins loaded by name (:func:`load`), in load order."""
    with _LOCK:
        return [p for p, _ in _LOADED.values()]


def add_registry(group: str, adopt: Callable[[object], list]) -> None:
    """Declare the registry of ``group``: ``adopt(obj)`` registers what it recognises in ``obj`` (a module
    or the object an entry point names) and returns the names it registered. Objects that plugins gave
    before the registry existed are handed to it now."""
    if group not in GROUPS:
        raise ValueError(f"plugins: unknown group {group!r} (allowed: {', '.join(GROUPS)})")
    with _LOCK:
        _ADOPT[group] = adopt
        for plugin, obj in list(_YIELDED):
            _adopt_one(group, plugin, obj, plugin.describe())


def _adopt_one(group: str, plugin: Plugin, obj, what: str) -> list:
    _CURRENT.append(plugin)
    try:
        return list(_ADOPT[group](obj))
    except ValueError as e:
        raise PluginError(f"{what}: {' '.join(str(e).split())}") from None
    finally:
        _CURRENT.pop()


def _adopt(plugin: Plugin, obj, what: str, groups=None) -> list:
    """Hand ``obj`` to the registries (``groups``, default all declared); the names registered. Kept for
    registries declared later only when every registry took it."""
    names = []
    for g in (groups if groups is not None else list(_ADOPT)):
        if g in _ADOPT:
            names += _adopt_one(g, plugin, obj, what)
    _YIELDED.append((plugin, obj))
    return names


# ---- by name: a file or a module ------------------------------------------------------------------


def is_file_spec(spec: str) -> bool:
    """A plugin named as a file (a name ending in ``.py`` or a path), not a module."""
    s = str(spec)
    return s.endswith(".py") or "/" in s or "\\" in s


def load(spec, base_dir=None, what: str = "--plugin") -> Plugin:
    """Import the plugin ``spec`` (a ``.py`` file, relative to ``base_dir`` if given and not absolute,
    or a module name) once per process and register what it defines; returns its record.

    ``what`` names where it was given in errors (``--plugin``, ``study.toml: study.plugins``)."""
    s = str(spec).strip()
    if not s:
        raise PluginError(f"{what}: empty plugin name (a Python file or a module name)")
    if is_file_spec(s):
        p = Path(s).expanduser()
        if not p.is_absolute() and base_dir is not None:
            p = Path(base_dir) / p
        from arvcas.util import files

        try:
            files.check_input(p, "plugin file", PluginError)
        except PluginError as e:
            raise PluginError(f"{what} {e}") from None
        if p.suffix != ".py":
            raise PluginError(f"{what} {s}: a plugin file is Python source, named *.py")
        return _load_file(p.resolve(), what)
    if not all(part.isidentifier() for part in s.split(".")):
        raise PluginError(f"{what} {s}: neither a Python file (*.py) nor a module name (like mylab.control)")
    return _load_module(s, what)


def _load_file(path: Path, what: str) -> Plugin:
    key = str(path)
    with _LOCK:
        if key in _LOADED:
            return _LOADED[key][0]
        name = _module_name(path)
        plugin = Plugin("file", key, name)
        module = sys.modules.get(name)
        if module is None or not _same_file(getattr(module, "__file__", None), path):
            spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            try:
                _running(plugin, lambda: spec.loader.exec_module(module), f"{what} {path}", path)
            except PluginError:
                sys.modules.pop(name, None)
                raise
        _adopt(plugin, module, f"{what} {path}")
        _LOADED[key] = (plugin, module)
        return plugin


def _load_module(name: str, what: str) -> Plugin:
    with _LOCK:
        if name in _LOADED:
            return _LOADED[name][0]
        plugin = Plugin("module", name, name)
        module = _running(plugin, lambda: importlib.import_module(name), f"{what} {name}")
        _adopt(plugin, module, f"{what} {name}")
        _LOADED[name] = (plugin, module)
        return plugin


def _running(plugin: Plugin, code: Callable[[], object], what: str, path: Path | None = None):
    """``code()`` (a plugin's import) run as ``plugin`` (:func:`current`); any failure of the plugin's code,
    SystemExit included, as one :class:`PluginError` line (``what``: the plugin, ``path``: its file)."""
    _CURRENT.append(plugin)
    try:
        return code()
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # noqa: BLE001 - whatever the plugin's code raises
        raise PluginError(f"{what}: {why(e, path)}") from None
    finally:
        _CURRENT.pop()


def _module_name(path: Path) -> str:
    """The file's stem, unless another module holds that name; else a private name from the path."""
    stem = path.stem
    if stem.isidentifier() and stem != "__init__":
        m = sys.modules.get(stem)
        if m is not None:
            if _same_file(getattr(m, "__file__", None), path):
                return stem
        else:
            try:
                found = importlib.util.find_spec(stem)
            except (ImportError, ValueError):
                found = None
            if found is None or _same_file(found.origin, path):
                return stem
    tag = hashlib.sha256(str(path).encode()).hexdigest()[:10]
    safe = "".join(ch if ch.isalnum() or ch == "_" else "_" for ch in stem)
    return f"arvcas_plugin_{safe}_{tag}"


def _same_file(a, b) -> bool:
    try:
        return a is not None and Path(a).resolve() == Path(b).resolve()
    except OSError:
        return False


def why(e: BaseException, path: Path | None = None) -> str:
    """One line: the exception and, when it has one, the place in the plugin's own code."""
    if isinstance(e, SyntaxError):
        where = f" ({Path(e.filename).name}, line {e.lineno})" if e.filename and e.lineno else ""
        return f"SyntaxError: {e.msg}{where}"
    msg = " ".join(str(e).split())
    where = ""
    frames = traceback.extract_tb(e.__traceback__)
    own = [f for f in frames if path is not None and _same_file(f.filename, path)] or \
          [f for f in frames if "importlib" not in f.filename and not f.filename.startswith("<frozen")]
    if own and own[-1].filename and Path(own[-1].filename).exists():
        where = f" ({Path(own[-1].filename).name}, line {own[-1].lineno})"
    return f"{type(e).__name__}: {msg}{where}" if msg else f"{type(e).__name__}{where}"


# ---- entry points -------------------------------------------------------------------------------------


def _entry_points(group: str) -> list:
    try:
        return list(importlib.metadata.entry_points(group=group))
    except Exception as e:  # noqa: BLE001 - a damaged installation: say so, never crash a command
        _FAILED.setdefault(group, {})["(metadata)"] = f"entry points of group {group}: {type(e).__name__}: {e}"
        return []


def _ep_text(ep) -> str:
    return f"{ep.name} = {ep.value}"


def _dist(ep) -> str:
    d = getattr(ep, "dist", None)
    if d is None:
        return ""
    try:
        return f"{d.metadata['Name'] or d.name} {d.version}"
    except Exception:  # noqa: BLE001
        return ""


def _load_ep(group: str, ep) -> list:
    """Load one entry point and register what it names; PluginError (one line) if it fails."""
    dist = _dist(ep)
    plugin = Plugin("entry point", ep.module, ep.module, f"{group}: {_ep_text(ep)}", dist)
    what = plugin.describe()
    _EP_DONE.setdefault(group, set()).add(_ep_text(ep))
    try:
        return _adopt(plugin, _running(plugin, ep.load, what), what, [group])
    except PluginError as e:
        _FAILED.setdefault(group, {})[_ep_text(ep)] = str(e)
        raise


def find(group: str, name: str) -> list:
    """Load the entry points of ``group`` named ``name`` (not loaded before); the names they registered.
    A failing one raises :class:`PluginError`: the caller asked for that name."""
    with _LOCK:
        done = _EP_DONE.setdefault(group, set())
        out = []
        for ep in _entry_points(group):
            if ep.name == name and _ep_text(ep) not in done:
                out += _load_ep(group, ep)
        return out


def load_group(group: str) -> list[str]:
    """Load every entry point of ``group`` not loaded before; the one-line failures (a broken plugin is
    reported, never raised: the caller lists what works)."""
    with _LOCK:
        if group not in _EP_ALL:
            done = _EP_DONE.setdefault(group, set())
            for ep in _entry_points(group):
                if _ep_text(ep) not in done:
                    try:
                        _load_ep(group, ep)
                    except PluginError:
                        pass  # recorded in _FAILED
            _EP_ALL.add(group)
        return failures(group)


def failures(group: str) -> list[str]:
    """The one-line failures of the entry points of ``group`` tried so far."""
    with _LOCK:
        return list(_FAILED.get(group, {}).values())


# ---- source files -------------------------------------------------------------------------------------


def source_files(module: str) -> list[str]:
    """The files whose code defines ``module``: its file, or every ``.py`` file of its top-level package
    when it is in one (a law's helpers in a sibling module count). Empty for a built-in module."""
    m = sys.modules.get(module)
    top = sys.modules.get(module.split(".")[0])
    if top is not None and getattr(top, "__path__", None) is not None:
        out = set()
        for d in top.__path__:
            out.update(str(f) for f in Path(d).rglob("*.py") if "__pycache__" not in f.parts)
        if out:
            return sorted(out)
    f = getattr(m, "__file__", None) if m is not None else None
    return [str(Path(f).resolve())] if f and str(f).endswith(".py") else []


def digest(paths) -> str:
    """sha256 over the files' bytes in order (an unreadable file counts by its name)."""
    h = hashlib.sha256()
    for p in paths:
        try:
            h.update(Path(p).read_bytes())
        except OSError:
            h.update(f"<unreadable {p}>".encode())
    return h.hexdigest()
