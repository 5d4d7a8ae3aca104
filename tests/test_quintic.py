"""One rest-to-rest quintic (arvcas.sim.trajectory.rest_to_rest) behind every NumPy and Python user: the
vehicle's minimum-jerk segments and the synthetic trials' arm moves (the command line's demo follows the
compiled scenario's arm motion, checked in tests/test_export.py). Checked against
NumPy's polynomial class (an independent evaluation of 10 s^3 - 15 s^4 + 6 s^5 and its derivatives), against
the compiled scenario's CasADi form, and bit for bit against the formulas each user wrote before it was
shared (so no committed number moves)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial import Polynomial

from arvcas.ident.synthetic import QuinticMoves
from arvcas.sim import profiles
from arvcas.sim.trajectory import min_jerk, rest_to_rest

S = np.linspace(0.0, 1.0, 1001)


def test_the_blend_is_the_minimum_jerk_polynomial():
    P = Polynomial([0, 0, 0, 10, -15, 6])
    for got, want in zip(rest_to_rest(S), (P(S), P.deriv()(S), P.deriv(2)(S))):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    b, bd, bdd = (np.array(x) for x in rest_to_rest(np.array([0.0, 1.0])))
    assert b.tolist() == [0.0, 1.0] and bd.tolist() == [0.0, 0.0] and bdd.tolist() == [0.0, 0.0]


def test_the_compiled_scenarios_quintic_is_the_same_polynomial():
    t0, t1 = 2.0, 7.0
    t = t0 + (t1 - t0) * S[1:-1]
    s, sd, sdd = (np.array(x.full()).ravel() for x in profiles.quintic(t, t0, t1))
    b, bd, bdd = rest_to_rest(S[1:-1])
    np.testing.assert_allclose(s, b, atol=1e-14)
    np.testing.assert_allclose(sd, bd / (t1 - t0), atol=1e-14)
    np.testing.assert_allclose(sdd, bdd / (t1 - t0) ** 2, atol=1e-13)


# the formulas as each user wrote them before the blend was shared: the numbers must not move by a bit
def _min_jerk_before(p0, p1, t0, t1, t):
    p0, p1 = np.atleast_1d(np.asarray(p0, float)), np.atleast_1d(np.asarray(p1, float))
    T = t1 - t0
    s = np.clip((np.asarray(t, float) - t0) / T, 0.0, 1.0)[:, None]
    d = p1 - p0
    return (p0 + d * (10 * s**3 - 15 * s**4 + 6 * s**5), d * (30 * s**2 - 60 * s**3 + 30 * s**4) / T,
            d * (60 * s - 180 * s**2 + 120 * s**3) / T**2)


def _moves_before(times, poses, t):
    q = np.empty(t.shape + (poses.shape[1],))
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    t0, t1 = times[k], times[k + 1]
    T = t1 - t0
    s = np.clip((t - t0) / T, 0.0, 1.0)
    moving = ((t >= t0) & (t <= t1))[..., None]
    a, b = poses[k], poses[k + 1]
    d = b - a
    q[:] = a + d * (10 * s**3 - 15 * s**4 + 6 * s**5)[..., None]
    qd[:] = np.where(moving, d * ((30 * s**2 - 60 * s**3 + 30 * s**4) / T)[..., None], 0.0)
    qdd[:] = np.where(moving, d * ((60 * s - 180 * s**2 + 120 * s**3) / T**2)[..., None], 0.0)
    return q, qd, qdd


@pytest.mark.parametrize("seed", range(5))
def test_every_user_computes_the_same_bits_as_before(seed):
    rng = np.random.default_rng(seed)
    p0, p1 = rng.normal(size=6), rng.normal(size=6)
    t0, t1 = rng.uniform(0, 5), rng.uniform(6, 20)
    t = np.sort(rng.uniform(-1, 25, 500))
    for got, want in zip(min_jerk(p0, p1, t0, t1, t), _min_jerk_before(p0, p1, t0, t1, t)):
        assert got.tobytes() == want.tobytes()
    times, poses = np.cumsum(rng.uniform(0.5, 3, 5)), rng.normal(size=(5, 6))
    for got, want in zip(QuinticMoves(times, poses)(t), _moves_before(times, poses, t)):
        assert got.tobytes() == want.tobytes()
