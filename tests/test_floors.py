"""CI's floor pins (.ci/floors.py): every runtime dependency of pyproject.toml pinned to the floor it declares,
and a dependency without a usable floor refused in one line. The install at the floors and the tests marked
``floor`` run in .ci/run (docs/testing.md)."""

from __future__ import annotations

import runpy
import tomllib
from pathlib import Path
from types import SimpleNamespace

import pytest
from packaging.requirements import Requirement
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def floors():
    return SimpleNamespace(**runpy.run_path(str(ROOT / ".ci" / "floors.py")))


def _pins(text: str) -> list[Requirement]:
    return [Requirement(line) for line in text.splitlines() if line and not line.startswith("#")]


def _pyproject(tmp_path: Path, *deps: str, test: tuple[str, ...] = ()) -> Path:
    p = tmp_path / "pyproject.toml"
    p.write_text("[project]\nname = 'x'\ndependencies = [" + ", ".join(repr(d) for d in deps) + "]\n"
                 "[project.optional-dependencies]\ntest = [" + ", ".join(repr(d) for d in test) + "]\n",
                 encoding="utf-8")
    return p


def test_every_runtime_dependency_is_pinned_to_the_lowest_version_it_admits(floors):
    deps = [Requirement(d) for d in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]]
    pins = _pins(floors.constraints())
    assert [p.name for p in pins] == [d.name for d in deps]
    for dep, pin in zip(deps, pins):
        (s,) = pin.specifier
        v = Version(s.version)
        assert s.operator == "==" and dep.specifier.contains(v), (dep, pin)
        # the lowest it admits: the version itself is one of its own lower bounds
        assert any(c.operator == ">=" and Version(c.version) == v for c in dep.specifier), (dep, pin)


def test_floor_clauses_and_markers(floors, tmp_path):
    p = _pyproject(tmp_path, "a>=1.2,<2", "B_c==3.0.1", "d~=1.4", "e>=0.9,>=1.1", "f>=1.0; python_version < '3'")
    assert [str(r) for r in _pins(floors.constraints(p))] == [
        "a==1.2", "B_c==3.0.1", "d==1.4", "e==1.1", 'f==1.0; python_version < "3"']


def test_the_test_requirements_of_the_floor_job_come_from_the_test_extra(floors, tmp_path):
    test = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["test"]
    kept = [line for line in floors.extra_requirements().splitlines() if not line.startswith("#")]
    assert kept and set(kept) <= set(test) and [Requirement(k).name for k in kept] == list(floors.FLOOR_TEST_NEEDS)
    p = _pyproject(tmp_path, "numpy>=1.24", test=("Pytest>=7", "pin>=2.7", "pytest_xdist>=3.8; python_version >= '3'"))
    assert floors.extra_requirements(p).splitlines()[1:] == ["Pytest>=7", "pytest_xdist>=3.8; python_version >= '3'"]
    p = _pyproject(tmp_path, "numpy>=1.24", test=("pin>=2.7",))
    with pytest.raises(floors.FloorError, match=r"optional-dependencies.test: no pytest, pytest-xdist \(the floor"):
        floors.extra_requirements(p)
    assert floors.main(["--test", str(p)]) == 1
    assert floors.main(["--test", "--check"]) == 2 and floors.main(["--bad"]) == 2


@pytest.mark.parametrize("dep,match", [
    ("numpy", r"'numpy' has no floor; give it one with >="),
    ("numpy; python_version >= '3'", r""""numpy; python_version >= '3'" has no floor"""),
    ("numpy<2", r"'numpy<2' has no floor"),
    ("casadi>=3.9,<3.8", r"'casadi>=3.9,<3.8': its floor 3.9 is outside its own bounds"),
    ("not a requirement!", r"'not a requirement!' is not a requirement"),
])
def test_a_dependency_without_a_usable_floor_is_refused_in_one_line(floors, tmp_path, dep, match):
    p = _pyproject(tmp_path, "scipy>=1.10", dep)
    with pytest.raises(floors.FloorError, match=r"pyproject.toml: \[project\] dependencies: " + match):
        floors.constraints(p)
    assert floors.main([str(p)]) == 1


def test_check_names_each_dependency_not_at_its_floor(floors, tmp_path, monkeypatch, capsys):
    p = _pyproject(tmp_path, "alpha>=1.2", "beta>=2.0", "gamma>=1", "delta>=1; python_version < '3'")
    installed = {"alpha": "1.2.0", "beta": "2.1"}

    def version(name):
        if name not in installed:
            raise floors.metadata.PackageNotFoundError(name)
        return installed[name]

    monkeypatch.setattr(floors.metadata, "version", version)
    assert floors.check(p) == ["beta: 2.1 installed, its floor is 2.0", "gamma: not installed (floor 1)"]
    assert floors.main(["--check", str(p)]) == 1
    assert "floors: not at the floor: beta: 2.1 installed" in capsys.readouterr().err
    installed.update(beta="2.0", gamma="1.0")
    assert floors.main(["--check", str(p)]) == 0
    assert capsys.readouterr().out == "floors: alpha 1.2, beta 2.0, gamma 1\n"
