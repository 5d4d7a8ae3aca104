"""Shared fixtures: the packaged parameters and the SX plant functions, built once per session."""

from __future__ import annotations

import pytest

from arvcas import params as _params
from arvcas import uvms as _uvms


@pytest.fixture(scope="session")
def params():
    """The packaged parameter file, loaded and validated (SI values)."""
    return _params.load()


@pytest.fixture(scope="session")
def plant():
    """The public plant functions (SX, evaluated in CasADi's VM) at the default n_quad = 5."""
    return _uvms.plant_functions(_uvms.ModelOptions(n_quad=5))
