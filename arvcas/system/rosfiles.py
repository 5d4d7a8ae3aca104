"""A ROS description's files, read for an import (:mod:`arvcas.system.uuv`, docs/importing.md): the ROS
packages under a few roots (for ``$(find pkg)``), a xacro file expanded with bounds on its elements, their
nesting, its time and its memory (macros and expressions can expand without bound), and uuv_simulator's YAML (its thruster allocation
matrix and thrust limits). Every fault is one line naming the file and what is wrong.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from arvcas.system import config, urdf

__all__ = ["ImportError_", "find_packages", "default_roots", "expand", "read_tam", "read_max_thrust",
           "rel_path", "MAX_PACKAGE_SCAN", "MAX_XACRO_ELEMENTS", "MAX_XACRO_DEPTH", "MAX_XACRO_SECONDS",
           "MAX_XACRO_BYTES", "XACRO_GRACE_SECONDS"]

MAX_PACKAGE_SCAN = 20000  # directories looked at when indexing ROS packages for $(find ...)
# Bounds of a xacro expansion (macros can expand exponentially: a macro calling another twice, 40 deep, is
# 2^40 elements): elements evaluated, their nesting, and seconds. The RexROV 2 + Oberon 7 of
# tests/data/uuv_rexrov2 evaluates 921 elements nested 10 deep in 0.5 s (measured), the RexROV 2 alone 417.
MAX_XACRO_ELEMENTS = 20_000
MAX_XACRO_DEPTH = 100
MAX_XACRO_SECONDS = 30.0
# the child process that expands a xacro file (expand): memory it may add, and the time it has past
# MAX_XACRO_SECONDS before it is killed (one expression can run without end inside Python: ${10**10**10})
MAX_XACRO_BYTES = 1 << 30
XACRO_GRACE_SECONDS = 5.0


class ImportError_(ValueError):
    """One-line error of an import (names the file and the element or option at fault)."""


def find_packages(roots: list[Path], error=ImportError_) -> dict[str, Path]:
    """ROS package name -> directory, for every ``package.xml`` under ``roots`` (hidden directories skipped;
    at most :data:`MAX_PACKAGE_SCAN` directories looked at)."""
    found: dict[str, Path] = {}
    seen = 0
    for root in roots:
        for d, dirs, files in os.walk(root):
            seen += 1
            if seen > MAX_PACKAGE_SCAN:
                raise error(f"{root}: more than {MAX_PACKAGE_SCAN} directories while looking for ROS packages: "
                            f"name the folders that hold them with --ros-path")
            dirs[:] = sorted(x for x in dirs if not x.startswith("."))
            if "package.xml" in files:
                try:
                    pxml = Path(d) / "package.xml"
                    text = pxml.read_text(encoding="utf-8", errors="replace")
                    urdf.refuse_dtd(text, str(pxml), ValueError)  # no entity is expanded
                    name = (ET.fromstring(text).findtext("name") or "").strip()
                except (ET.ParseError, OSError, ValueError):
                    continue
                if name and name not in found:
                    found[name] = Path(d).resolve()
    return found


def _package_of(path: Path) -> Path | None:
    for d in path.resolve().parents:
        if (d / "package.xml").is_file():
            return d
    return None


def rel_path(path: Path) -> str:
    """A file named as ROS does: its package's folder name and the path in it (else its name)."""
    pkg = _package_of(path)
    return path.name if pkg is None else f"{pkg.name}/{path.resolve().relative_to(pkg)}"


def default_roots(path: Path) -> list[Path]:
    """Where ``$(find pkg)`` looks by default: the folder holding the input's ROS package (a workspace's
    ``src``), or the input's own folder."""
    pkg = _package_of(path)
    return [pkg.parent if pkg is not None else path.resolve().parent]


def expand(path: Path, packages: dict[str, Path], args: dict[str, str], error=ImportError_) -> tuple[str, list[str]]:
    """The URDF text of a xacro file (``$(find pkg)`` resolved in ``packages``, ``$(arg x)`` from ``args``) and
    the files it included; a plain URDF is returned as read.

    Where processes fork (Linux, macOS) the expansion runs in a child process with at most
    :data:`MAX_XACRO_BYTES` more memory than this one, killed after :data:`MAX_XACRO_SECONDS` (plus
    :data:`XACRO_GRACE_SECONDS`): a single ``${...}`` expression can run without end inside Python
    (``${10**10**10}``) or double a string 60 times, which no count of elements sees."""
    import multiprocessing as mp

    if "fork" not in mp.get_all_start_methods():
        return _expand(path, packages, args, error)
    ctx = mp.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_expand_child, args=(send, path, packages, args, error), daemon=True)
    child.start()
    send.close()
    try:
        if not recv.poll(MAX_XACRO_SECONDS + XACRO_GRACE_SECONDS):
            raise error(f"{path}: xacro: the expansion took more than {MAX_XACRO_SECONDS:g} s; refused "
                        f"(arvcas.system.rosfiles.MAX_XACRO_SECONDS)")
        try:
            kind, *value = recv.recv()
        except EOFError:  # the child died without a word (killed by the system: out of memory)
            child.join(5)
            raise error(f"{path}: xacro: the expansion stopped without a result (exit code {child.exitcode}); "
                        f"refused") from None
    finally:
        if child.is_alive():
            child.kill()
        child.join(5)
        recv.close()
    if kind == "error":
        raise error(value[0])
    return value[0], value[1]


def _expand_child(send, path, packages, args, error) -> None:
    """In a forked child: bound the memory, expand, send ("ok", text, includes) or ("error", line)."""
    try:
        import resource

        with open("/proc/self/statm") as fh:  # the address space this process already has (Linux)
            have = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        resource.setrlimit(resource.RLIMIT_AS, (have + MAX_XACRO_BYTES, resource.getrlimit(resource.RLIMIT_AS)[1]))
    except (OSError, ValueError, ImportError):
        pass  # no /proc (macOS) or a lower hard limit: the time bound stays
    try:
        send.send(("ok", *_expand(path, packages, args, error)))
    except MemoryError:
        send.send(("error", f"{path}: xacro: the expansion needed more than {MAX_XACRO_BYTES >> 20} MiB; refused "
                            f"(arvcas.system.rosfiles.MAX_XACRO_BYTES)"))
    except Exception as e:  # noqa: BLE001 - error's one line, or xacro's own
        send.send(("error", str(e) if isinstance(e, (ImportError_, error)) else f"{path}: xacro: {e}"))
    finally:
        send.close()


def _expand(path: Path, packages: dict[str, Path], args: dict[str, str], error=ImportError_) -> tuple[str, list[str]]:
    """:func:`expand` in this process (the element, depth and time bounds of :func:`_bounded`)."""
    from arvcas.util.files import read_text

    text = read_text(path, "robot description", error)
    if "xacro" not in text:
        return text, []
    try:
        import xacro
        from xacro import substitution_args as sa
    except ImportError:
        raise error(f"{path}: a xacro file: expanding it needs xacro: pip install 'arvcas[uuv]' (or give the "
                    f"URDF that `xacro` writes)") from None

    def find(pkg: str) -> str:
        if pkg not in packages:
            raise error(f"{path}: $(find {pkg}): no ROS package '{pkg}' under the --ros-path folders "
                        f"(found: {', '.join(sorted(packages)[:12]) or 'none'}){config.closest(pkg, packages)}")
        return str(packages[pkg])

    old = sa._eval_find, sa._eval_dict.get("find")
    sa._eval_find, sa._eval_dict["find"] = find, find
    real_parse = xacro.parse

    def parse_without_dtd(inp, filename=None):  # the file and every include: no DTD, no entity expanded
        if inp is None:
            with open(os.path.join(xacro.root_dir, filename), encoding="utf-8") as fh:
                inp = fh.read()
        elif hasattr(inp, "read"):
            inp = inp.read()
        if isinstance(inp, (str, bytes)):
            urdf.refuse_dtd(inp, filename or str(path), error)
        return real_parse(inp, filename)

    xacro.parse = parse_without_dtd
    xacro.all_includes = []
    real_eval_all = xacro.eval_all
    xacro.eval_all = _bounded(real_eval_all, path, error)
    try:
        xacro.init_stacks(None)
        with contextlib.redirect_stderr(io.StringIO()):  # xacro's warnings (redefined symbols, ...)
            doc = xacro.process_file(str(path.resolve()), mappings=dict(args), verbosity=0)
        return doc.toxml(), list(xacro.all_includes)
    except (ImportError_, error):
        raise
    except Exception as e:  # noqa: BLE001 (xacro's own message, one line)
        raise error(f"{path}: xacro: {' '.join(str(e).split())}") from None
    finally:
        sa._eval_find, sa._eval_dict["find"] = old
        xacro.parse = real_parse
        xacro.eval_all = real_eval_all
        xacro.init_stacks(None)


def _bounded(eval_all, path: Path, error):
    """xacro's ``eval_all`` (it evaluates one element and, recursively, what it expands to) counted: more than
    :data:`MAX_XACRO_ELEMENTS` elements, a nesting deeper than :data:`MAX_XACRO_DEPTH` or more than
    :data:`MAX_XACRO_SECONDS` stops the expansion with one line naming the file and the bound."""
    import time

    state = {"n": 0, "depth": 0, "t0": time.monotonic()}

    def counted(node, macros, symbols):
        state["n"] += 1
        state["depth"] += 1
        try:
            if state["n"] > MAX_XACRO_ELEMENTS:
                raise error(f"{path}: xacro: the expansion passed {MAX_XACRO_ELEMENTS:,} elements (a macro that "
                            f"expands without bound?); refused (arvcas.system.rosfiles.MAX_XACRO_ELEMENTS)")
            if state["depth"] > MAX_XACRO_DEPTH:
                raise error(f"{path}: xacro: elements nested more than {MAX_XACRO_DEPTH} deep (a macro that "
                            f"calls itself?); refused (arvcas.system.rosfiles.MAX_XACRO_DEPTH)")
            if time.monotonic() - state["t0"] > MAX_XACRO_SECONDS:
                raise error(f"{path}: xacro: the expansion took more than {MAX_XACRO_SECONDS:g} s after "
                            f"{state['n']:,} elements; refused (arvcas.system.rosfiles.MAX_XACRO_SECONDS)")
            return eval_all(node, macros, symbols)
        finally:
            state["depth"] -= 1

    return counted


def _yaml(path: Path, what: str, error) -> Any:
    """A YAML file (uuv_simulator's configuration), parsed safely; one-line errors naming it."""
    from arvcas.util.files import read_text

    try:
        import yaml
    except ImportError:
        raise error(f"{path}: reading YAML needs PyYAML: pip install 'arvcas[uuv]'") from None
    try:
        return yaml.safe_load(read_text(path, what, error))
    except yaml.YAMLError as e:
        raise error(f"{path}: malformed YAML: {' '.join(str(e).split())}") from None


def read_tam(path: Path, error=ImportError_) -> np.ndarray:
    """uuv_simulator's ``TAM.yaml`` (``tam:`` rows, the thruster manager's allocation matrix in its
    ``base_link`` frame, FLU): a 6 x n array."""
    doc = _yaml(path, "TAM file", error)
    tam = doc.get("tam") if isinstance(doc, dict) else None
    try:
        A = np.array(tam, dtype=float)
    except (TypeError, ValueError):
        A = np.zeros(0)
    if A.ndim != 2 or A.shape[0] != 6 or not np.isfinite(A).all():
        raise error(f"{path}: tam: expected 6 rows of numbers, one column per thruster")
    return A


def read_max_thrust(path: Path, n: int, error=ImportError_) -> list[float]:
    """``thruster_manager.max_thrust`` of a uuv_simulator ``thruster_manager.yaml`` (a number or one per
    thruster): the manager clips each thrust to +- it."""
    doc = _yaml(path, "thruster manager file", error)
    tm = doc.get("thruster_manager", doc) if isinstance(doc, dict) else None
    v = tm.get("max_thrust") if isinstance(tm, dict) else None
    vals = v if isinstance(v, list) else [v] * n
    if len(vals) != n or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                                 and x > 0 for x in vals):
        raise error(f"{path}: thruster_manager.max_thrust: expected a positive number or {n} of them, got {v!r}")
    return [float(x) for x in vals]
