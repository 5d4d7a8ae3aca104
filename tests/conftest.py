"""Shared fixtures: the packaged parameters and the SX plant functions, built once per session; a build cache per module."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from arvcas.build import codegen as _codegen
from arvcas.system import params as _params
from arvcas.model import uvms as _uvms

# Builds that name no level compile at -O0 (ARVCAS_OPT_LEVEL, inherited by the command lines the tests start):
# a run compiles about 4x faster and computes the same bits (tests/test_closedloop.py compares -O0 with -O2);
# a test whose property depends on the optimiser names its level. ARVCAS_OPT_LEVEL=-O2 runs the suite at the
# shipped level (docs/testing.md).
os.environ.setdefault(_codegen.OPT_LEVEL_ENV, "-O0")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A private build cache (``ARVCAS_CACHE``, mode 0700) for the tests of one module."""
    d = tmp_path_factory.mktemp("arvcas-cache")
    os.chmod(d, 0o700)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ARVCAS_CACHE", str(d))
        yield d


@pytest.fixture
def fresh(monkeypatch):
    """A process that has loaded no plugin: empty plugin state; the controllers and objectives a test's
    plugins register, and their modules (named ``toy_*`` by the tests), are removed by ``clean()`` (the
    fixture's value: a test calls it to stand for a new process) and afterwards."""
    import sys

    from arvcas.controllers import base
    from arvcas.util import plugins
    from arvcas.metrics import objectives

    for name in ("_LOADED", "_EP_DONE", "_FAILED"):
        monkeypatch.setattr(plugins, name, {})
    monkeypatch.setattr(plugins, "_YIELDED", [])
    monkeypatch.setattr(plugins, "_EP_ALL", set())
    monkeypatch.setattr(objectives, "_REGISTRY", dict(objectives._REGISTRY))
    monkeypatch.setattr(objectives, "_ORIGIN", dict(objectives._ORIGIN))
    laws, objs = set(base.names()), set(objectives._REGISTRY)

    def clean():
        for state in (plugins._LOADED, plugins._EP_DONE, plugins._FAILED, plugins._YIELDED, plugins._EP_ALL):
            state.clear()
        for n in set(base.names()) - laws:
            base.unregister(n)
        for n in set(objectives._REGISTRY) - objs:
            del objectives._REGISTRY[n]
            objectives._ORIGIN.pop(n, None)
        for m in [m for m in sys.modules if m.startswith(("toy_", "arvcas_plugin_"))]:
            del sys.modules[m]

    clean()
    yield clean
    clean()


@pytest.fixture(scope="session")
def params():
    """The packaged parameter file, loaded and validated (SI values)."""
    return _params.load()


@pytest.fixture(scope="session")
def plant():
    """The public plant functions (SX, evaluated in CasADi's VM) at the default n_quad = 5."""
    return _uvms.plant_functions(_uvms.ModelOptions(n_quad=5))


@pytest.fixture(scope="session")
def dry(params):
    """The parameters with no fluid (env.rho = 0): the case Pinocchio can reproduce exactly."""
    return params.replace({"env.rho": 0.0})


@pytest.fixture(scope="session")
def pin_models(dry):
    """Pinocchio models of vehicle + arm built from the same data file, payload 0, 0.5 and 1."""
    import pinocchio_model as pm

    return {pl: pm.build(dry, payload=pl) for pl in (0.0, 0.5, 1.0)}



# Under xdist (--dist loadscope --no-loadscope-reorder, .ci/run) the modules are handed to the workers in the
# order collected: the costliest first, by the CPU seconds the last measurement of the whole suite gave each
# (results/ci/suite.json, benchmarks/ci_cost.py --suite), so that no worker is left with a long module at the
# end while the other idles. A module it does not list comes after those it lists. Without a complete
# measurement, and in a run on one process, pytest's order is kept.
SUITE_COSTS = Path(__file__).resolve().parents[1] / "results" / "ci" / "suite.json"


def _module_costs() -> dict[str, float]:
    """CPU seconds per test file from a complete measurement of the suite; none from an interrupted one (it
    would send the modules it did not reach last, whatever they cost)."""
    try:
        doc = json.loads(SUITE_COSTS.read_text(encoding="utf-8"))
        if doc.get("complete") is not True:
            return {}
        return {str(f["file"]): float(f["tests_cpu_s"]) for f in doc["files"]}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def pytest_collection_modifyitems(session, config, items):
    if not hasattr(config, "workerinput"):  # not an xdist worker
        return
    cost = _module_costs()
    if cost:
        items.sort(key=lambda it: -cost.get(it.path.name, 0.0))  # stable: each module's own order is kept


# Skips a CI run allows: what depends on the machine rather than on what was installed (the CI runs as root;
# .ci/run installs Chromium where it can and says so when it cannot). With ARVCAS_NO_SKIP set (.ci/run sets
# it) any other skip fails the run: a test extra that did not install or a tool that is missing is then an
# error, not a test that silently does not run.
ALLOWED_SKIPS = ("root may write to any directory", "chromium is not installed")
_SKIPPED: list = []


def _note_skip(report) -> None:
    if report.skipped and not hasattr(report, "wasxfail"):
        _SKIPPED.append(report)


pytest_runtest_logreport = pytest_collectreport = _note_skip


def _bad_skips() -> list:
    if not os.environ.get("ARVCAS_NO_SKIP"):
        return []
    return [r for r in _SKIPPED if not any(a in str(r.longrepr) for a in ALLOWED_SKIPS)]


def pytest_sessionfinish(session, exitstatus):
    if _bad_skips() and exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter):
    bad = _bad_skips()
    if bad:
        terminalreporter.write_line(f"ARVCAS_NO_SKIP: {len(bad)} skip(s) CI does not allow:", red=True)
        for r in bad:
            terminalreporter.write_line(f"  {r.nodeid}: {r.longrepr}")
