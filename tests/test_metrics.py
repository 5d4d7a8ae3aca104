"""CHAT (eq. 42), RMSE (eq. 43), Table 3 data and the docs/model.md §7 objectives, against hand-worked values."""

import numpy as np
import pytest

from arvcas.metrics import DOFS, chat, normalised_objectives, rmse, table3

# docs/model.md §6 / paper Table 3, typed here independently of data/table3.toml
SPEC_CHAT_AGSTA = [0.0363, 0.0749, 0.1045, 0.0903, 0.1173, 0.1006]
SPEC_CHAT_PROPOSED = [0.0285, 0.0462, 0.0672, 0.0538, 0.0887, 0.0662]
SPEC_RMSE_AGSTA = [6.1005e-4, 6.0119e-4, 7.5175e-4, 7.5865e-4, 7.7607e-4, 5.6136e-4]
SPEC_RMSE_PROPOSED = [5.9895e-4, 5.8173e-4, 5.1327e-4, 5.3599e-4, 7.5049e-4, 5.5314e-4]


def test_chat_hand_values():
    # N + 1 = 4 samples, N = 3 differences per DOF
    tau = np.array([
        [0.0, 1.0, 5.0, 0.0, 0.0, -1.0],
        [1.0, 1.0, 3.0, 0.0, 0.5, 1.0],
        [3.0, 1.0, 4.0, 0.0, 0.0, -1.0],
        [0.0, 1.0, 4.0, 3.0, 0.5, 1.0],
    ])
    # DOF 0: |1| + |2| + |-3| = 6 -> 2; DOF 2: 2 + 1 + 0 = 3 -> 1; DOF 3: 3 -> 1; DOF 4: 1.5 -> 0.5;
    # DOF 5: 2 + 2 + 2 -> 2
    assert np.allclose(chat(tau), [2.0, 0.0, 1.0, 1.0, 0.5, 2.0], rtol=0, atol=1e-15)
    assert chat(tau).shape == (6,)
    assert chat(tau[:, 0]) == pytest.approx(2.0, abs=1e-15)  # one DOF


def test_rmse_hand_values():
    e = np.array([
        [3.0, 1.0, 0.0, -2.0, 1e-3, 0.0],
        [4.0, -1.0, 0.0, 2.0, -1e-3, 0.0],
        [0.0, 1.0, 0.0, -2.0, 1e-3, 6.0],
        [0.0, -1.0, 0.0, 2.0, -1e-3, 0.0],
    ])
    # DOF 0: sqrt((9 + 16)/4) = 2.5; DOF 5: sqrt(36/4) = 3
    assert np.allclose(rmse(e), [2.5, 1.0, 0.0, 2.0, 1e-3, 3.0], rtol=1e-15, atol=0)
    assert rmse(e).shape == (6,)


def test_rejects_bad_shapes():
    with pytest.raises(ValueError):
        chat(np.zeros((1, 6)))  # one sample, no difference
    with pytest.raises(ValueError):
        rmse(np.zeros((0, 6)))
    with pytest.raises(ValueError):
        chat(np.zeros((3, 6, 2)))
    with pytest.raises(ValueError):
        normalised_objectives(np.ones(5), np.ones(6))


def test_table3_matches_spec():
    t = table3()
    assert DOFS == ("x", "y", "z", "phi", "theta", "psi")
    assert np.array_equal(t.chat_agsta, SPEC_CHAT_AGSTA)
    assert np.array_equal(t.chat_proposed, SPEC_CHAT_PROPOSED)
    assert np.array_equal(t.rmse_agsta, SPEC_RMSE_AGSTA)
    assert np.array_equal(t.rmse_proposed, SPEC_RMSE_PROPOSED)
    with pytest.raises(ValueError):
        t.chat_agsta[0] = 1.0  # one source of truth: read-only


def test_normalised_objectives():
    # the paper's AGSTA run scores (1, 1) by construction
    f = normalised_objectives(SPEC_CHAT_AGSTA, SPEC_RMSE_AGSTA)
    assert f == pytest.approx((1.0, 1.0), abs=1e-15)
    # the paper's proposed run: mean of the per-DOF ratios, by hand
    # CHAT: 0.0285/0.0363 = 0.785124, 0.0462/0.0749 = 0.616822, 0.0672/0.1045 = 0.643062,
    #       0.0538/0.0903 = 0.595792, 0.0887/0.1173 = 0.756181, 0.0662/0.1006 = 0.658052 -> 0.675839
    # RMSE: 0.981805, 0.967631, 0.682767, 0.706505, 0.967039, 0.985357 -> 0.881851
    f_chat, f_rmse = normalised_objectives(SPEC_CHAT_PROPOSED, SPEC_RMSE_PROPOSED)
    assert f_chat == pytest.approx(0.675839, abs=1e-6)
    assert f_rmse == pytest.approx(0.881851, abs=1e-6)
    # a DOF twice as bad as AGSTA adds 1/6
    c = np.array(SPEC_CHAT_AGSTA)
    c[3] *= 2
    assert normalised_objectives(c, SPEC_RMSE_AGSTA)[0] == pytest.approx(1 + 1 / 6, abs=1e-15)
