"""Typed public inputs: arvcas.dynamics and Run take real numeric arrays only (complex numbers lost their
imaginary part, booleans and masked arrays were read as numbers), seeds are integers, the payload is a
fraction in [0, 1], and a parameter vector of another system's layout is refused by name."""

from __future__ import annotations

import numpy as np
import pytest

import arvcas
from arvcas.sim.run import SimulationError

X, T, Q = np.zeros(12), np.zeros(6), np.zeros(6)


@pytest.fixture(scope="module")
def uvms():
    return arvcas.dynamics("uvms_rhs")


@pytest.mark.parametrize("args, message", [
    ((X.astype(complex), T, Q, Q, Q, 0.5), "uvms_rhs: x: expected real numbers (float or integer), got complex"),
    ((np.ma.array(X), T, Q, Q, Q, 0.5), "uvms_rhs: x: a masked array is not accepted"),
    ((X, T, Q, Q, Q, True), "uvms_rhs: payload: expected real numbers (float or integer), got booleans"),
    ((X, ["a"] * 6, Q, Q, Q, 0.5), "uvms_rhs: tau: expected real numbers (float or integer), got strings"),
    ((X, T, Q, Q, Q, 1.5), "uvms_rhs: payload: a fraction of the system's payload, in [0, 1], got 1.5"),
    ((X, T, Q, Q, Q, np.array([0.2, -0.1])), "payload: a fraction of the system's payload, in [0, 1], got -0.1"),
])
def test_dynamics_takes_real_arrays_and_a_payload_fraction(uvms, args, message):
    with pytest.raises(ValueError) as e:
        uvms(*args)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_dynamics_refuses_another_systems_parameters(uvms):
    blue = arvcas.load_system("bluerov2_heavy_alpha5").params
    with pytest.raises(ValueError, match="params: of system 'bluerov2_heavy_alpha5', whose parameter layout is not"):
        uvms(X, T, Q, Q, Q, 0.5, params=blue)
    np.testing.assert_array_equal(uvms(X, T, Q, Q, Q, 0.5, params=arvcas.load_system().params), uvms(X, T, Q, Q, Q, 0.5))


def test_run_takes_real_arrays_and_integer_seeds():
    run = arvcas.Run("pid").compile()
    g = run.default_gains()
    cases = [
        (lambda: run.simulate(g.astype(complex)), "gains: expected real numbers (float or integer), got complex"),
        (lambda: run.simulate(np.ma.array(g)), "gains: a masked array is not accepted"),
        (lambda: run.simulate(g, uncertainty=[1, 1, 1, 1j]), "uncertainty: expected real numbers"),
        (lambda: run.simulate(g, seed=1.5), "seed: must be an integer"),
        (lambda: run.simulate(g, seed=True), "seed: must be an integer"),
        (lambda: run.simulate(g, noise_scale=True), "noise_scale: must be a finite number >= 0"),
        (lambda: run.batch(np.stack([g, g]).astype(complex)), "gains: expected real numbers"),
        (lambda: run.many(g, seeds=[0, 1.5]), "seeds: expected integers, got floats"),
        (lambda: run.many(g, seeds=[True]), "seeds: expected integers, got booleans"),
        (lambda: run.many(g, seeds=[2**63]), "seeds: every value must be an integer with 0 <= v < 2**63"),
        (lambda: run.many(g, seeds=[0], phase=[["x"] * 6]), "phase: expected real numbers"),
    ]
    for call, message in cases:
        with pytest.raises(ValueError) as e:
            call()
        assert message in str(e.value) and "\n" not in str(e.value), (message, str(e.value))
    assert isinstance(SimulationError("x"), ValueError)
