"""Shared fixtures: the packaged parameters and the SX plant functions, built once per session; a build cache per module."""

from __future__ import annotations

import os

import pytest

from arvcas.system import params as _params
from arvcas.model import uvms as _uvms


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A private build cache (``ARVCAS_CACHE``, mode 0700) for the tests of one module."""
    d = tmp_path_factory.mktemp("arvcas-cache")
    os.chmod(d, 0o700)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ARVCAS_CACHE", str(d))
        yield d


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
