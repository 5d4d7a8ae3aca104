"""The implicit-GSTA controller in the closed loop (docs/model.md §5b), against the explicit proposed one at
Table 2 gains, seed 0. The block-level tests (closed form vs root solve; no chattering on a scalar
perturbed plant) are in test_gsta.py.

Measured (arvcas 0.1.0, seed 0, h = 0.1 s; see results/beyond/README.md):
with the scenario's sensor noise, CHAT implicit / proposed = 1.01 .. 1.04 per DOF (noise dominates
CHAT, and the implicit step does not filter it); without sensor noise (noise_scale = 0) the ratio is
0.89 .. 1.01, lower in 5 of 6 DOF: the discretisation chattering the implicit step removes is a small
part of this loop's CHAT. RMSE is lower in every DOF in both cases.
"""

from __future__ import annotations

import numpy as np
import pytest

from arvcas.controllers import gains
from arvcas.sim import scenario
from arvcas.sim.simulation import simulate


@pytest.fixture(scope="module")
def cfg():
    return scenario.load_scenario()


@pytest.fixture(scope="module")
def runs(cfg):
    return {(c, ns): simulate(c, seed=0, cfg=cfg, noise_scale=ns)
            for c in ("implicit", "proposed") for ns in (1.0, 0.0)}


def test_implicit_runs_with_the_proposed_gains(runs):
    r = runs[("implicit", 1.0)]
    assert r.ok and r.controller == "implicit"
    assert np.array_equal(r.gains, gains.default_gains("proposed"))
    assert np.all(np.isfinite(r.tau_cmd)) and np.all(np.abs(r.e[r.t >= 40.0]) < 0.01)  # keeps station
    # the adaptive law is the proposed one (explicit update): never below k1min once above it
    kmin = np.asarray(gains.unpack("proposed", r.gains)["k1min"])
    above = np.maximum.accumulate(r.k1 >= kmin, axis=0)
    assert np.all(r.k1[above] >= kmin[np.nonzero(above)[1]] - 1e-12)


def test_implicit_vs_explicit_chat_with_and_without_noise(runs):
    noisy = runs[("implicit", 1.0)].chat / runs[("proposed", 1.0)].chat
    clean = runs[("implicit", 0.0)].chat / runs[("proposed", 0.0)].chat
    # with sensor noise the two steps chatter alike (measured ratios 1.014 .. 1.039)
    assert np.all(np.abs(noisy - 1.0) < 0.08)
    # without it the implicit step chatters less in most DOF (measured 0.886 .. 1.008, 5 of 6 below 1)
    assert np.sum(clean < 1.0) >= 4 and np.mean(clean) < 0.97
    # and it tracks at least as well in every DOF (RMSE ratio measured 0.90 .. 0.99 noisy, 0.86 .. 0.97 clean)
    for ns in (1.0, 0.0):
        assert np.all(runs[("implicit", ns)].rmse <= runs[("proposed", ns)].rmse)
