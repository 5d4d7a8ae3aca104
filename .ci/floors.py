"""The floor versions of arvcas's runtime dependencies, read from pyproject.toml (their one source).

    python .ci/floors.py [PYPROJECT]            print a pip constraints file: each dependency of
                                                [project] dependencies pinned to its floor (casadi==3.7, ...)
    python .ci/floors.py --test [PYPROJECT]     print the requirements of the [test] extra that the floor
                                                tests need (FLOOR_TEST_NEEDS), for pip install -r
    python .ci/floors.py --check [PYPROJECT]    exit 1 unless every dependency installed in this Python is
                                                at its floor (after the install under those constraints)

The floor of a requirement is the version of its ``>=`` (or ``==``, ``~=``) clause; a dependency without
one is refused in one line, as is a floor that its own other clauses exclude (``>=3.9,<3.8``). The pins are
exact under PEP 440: ``casadi==3.7`` is 3.7.0, not 3.7.1. Only ``[project] dependencies`` are pinned: the
test requirements are not arvcas's runtime floors and install at what pip picks under these pins. CI's floor job
(.ci/run, docs/testing.md) installs the wheel with them and runs the tests marked ``floor``.
"""

from __future__ import annotations

import sys
import tomllib
from importlib import metadata
from pathlib import Path

from packaging.requirements import InvalidRequirement, Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

FLOOR_OPS = (">=", "==", "~=")
DEFAULT = Path(__file__).resolve().parents[1] / "pyproject.toml"
# the test requirements (of the [test] extra, at its bounds) that the floor job installs: what the files holding
# a floor test import at their top. Not the whole extra: it installs in 141 s against 35 s (docs/testing.md),
# and pin cannot be installed beside numpy's floor (every release from 2.7 on needs numpy >= 1.26)
FLOOR_TEST_NEEDS = ("pytest", "pytest-xdist")
USAGE = "usage: python .ci/floors.py [--test | --check] [PYPROJECT]"


class FloorError(ValueError):
    """A dependency of pyproject.toml without a usable floor (one line, naming the file and the dependency)."""


def _project(pyproject: Path) -> dict:
    try:
        return tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]
    except (OSError, tomllib.TOMLDecodeError, KeyError) as e:
        raise FloorError(f"{pyproject}: [project] cannot be read ({e!r})") from None


def _requirements(pyproject: Path, key: str) -> list[tuple[str, Requirement]]:
    where = f"{pyproject}: [project] {key}"
    project = _project(pyproject)
    texts = project.get("optional-dependencies", {}).get("test") if key == "optional-dependencies.test" \
        else project.get(key)
    if not isinstance(texts, list):
        raise FloorError(f"{where}: missing, or not a list of requirements")
    out = []
    for text in texts:
        try:
            out.append((text, Requirement(text)))
        except InvalidRequirement as e:
            raise FloorError(f"{where}: {text!r} is not a requirement ({e})") from None
    return out


def floors(pyproject: Path = DEFAULT) -> list[tuple[Requirement, Version]]:
    """Each runtime dependency of ``pyproject`` with its floor version, in the file's order."""
    out = []
    for text, req in _requirements(pyproject, "dependencies"):
        low = [Version(s.version) for s in req.specifier if s.operator in FLOOR_OPS]
        where = f"{pyproject}: [project] dependencies: {text!r}"
        if not low:
            raise FloorError(f"{where} has no floor; give it one with >= (the oldest release tested)")
        floor = max(low)
        if not req.specifier.contains(floor, prereleases=True):
            raise FloorError(f"{where}: its floor {floor} is outside its own bounds")
        out.append((req, floor))
    return out


def applying(pyproject: Path = DEFAULT) -> list[tuple[Requirement, Version]]:
    """:func:`floors` less the dependencies whose environment marker excludes this Python."""
    return [(r, f) for r, f in floors(pyproject) if r.marker is None or r.marker.evaluate()]


def constraints(pyproject: Path = DEFAULT) -> str:
    """The text of a pip constraints file pinning every runtime dependency to its floor."""
    lines = [f"# written by .ci/floors.py from {pyproject.name}: each runtime dependency at its floor"]
    for req, floor in floors(pyproject):
        lines.append(f"{req.name}=={floor}" + (f"; {req.marker}" if req.marker else ""))
    return "\n".join(lines) + "\n"


def extra_requirements(pyproject: Path = DEFAULT) -> str:
    """The requirements of the [test] extra named in :data:`FLOOR_TEST_NEEDS`, one a line, as the extra
    gives them; one that the extra lacks is refused in one line."""
    test = {canonicalize_name(r.name): text for text, r in _requirements(pyproject, "optional-dependencies.test")}
    missing = [n for n in FLOOR_TEST_NEEDS if canonicalize_name(n) not in test]
    if missing:
        raise FloorError(f"{pyproject}: [project] optional-dependencies.test: no {', '.join(missing)} "
                         f"(the floor job installs it: FLOOR_TEST_NEEDS of .ci/floors.py)")
    lines = [f"# written by .ci/floors.py from {pyproject.name}: what the floor tests need of the [test] extra"]
    return "\n".join(lines + [test[canonicalize_name(n)] for n in FLOOR_TEST_NEEDS]) + "\n"


def check(pyproject: Path = DEFAULT) -> list[str]:
    """Each runtime dependency whose installed version (in this Python) is not its floor, as one line each."""
    bad = []
    for req, floor in applying(pyproject):
        try:
            have = Version(metadata.version(req.name))
        except metadata.PackageNotFoundError:
            bad.append(f"{req.name}: not installed (floor {floor})")
            continue
        if have != floor:
            bad.append(f"{req.name}: {have} installed, its floor is {floor}")
    return bad


def main(argv: list[str]) -> int:
    modes = [a for a in argv if a in ("--test", "--check")]
    args = [a for a in argv if a not in modes]
    if len(modes) > 1 or len(args) > 1 or any(a.startswith("-") for a in args):
        print(USAGE, file=sys.stderr)
        return 2
    path = Path(args[0]) if args else DEFAULT
    try:
        if not modes:
            sys.stdout.write(constraints(path))
            return 0
        if modes == ["--test"]:
            sys.stdout.write(extra_requirements(path))
            return 0
        bad = check(path)
    except FloorError as e:
        print(f"floors: {e}", file=sys.stderr)
        return 1
    if bad:
        print("floors: not at the floor: " + "; ".join(bad), file=sys.stderr)
        return 1
    print("floors: " + ", ".join(f"{r.name} {f}" for r, f in applying(path)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
