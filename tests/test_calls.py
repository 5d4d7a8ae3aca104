"""arvcas.build.calls: zero-copy calls and the thread-pool batch against plain CasADi evaluation."""

import casadi as ca
import numpy as np
import pytest

from arvcas.build import calls


@pytest.fixture(scope="module")
def f():
    """A function with a per-run vector, a per-run matrix, a shared matrix and a shared scalar."""
    a, B, C, s = ca.SX.sym("a", 3), ca.SX.sym("B", 2, 4), ca.SX.sym("C", 3, 2), ca.SX.sym("s")
    y = ca.mtimes(C.T, a) * s + ca.sum2(B)
    return ca.Function("f", [a, B, C, s], [y, ca.sin(a) + s], ["a", "B", "C", "s"], ["y", "z"])


def _plain(f, A, Bs, C, s):
    outs = [f(A[:, j], Bs[:, 4 * j:4 * j + 4], C, s) for j in range(A.shape[1])]
    return [np.hstack([np.array(o[i]) for o in outs]) for i in range(f.n_out())]


@pytest.mark.parametrize("n_threads", [1, 2, 3, 16])
def test_call_many_equals_one_call_per_run(f, n_threads):
    rng = np.random.default_rng(1)
    n = 11
    A, Bs, C, s = rng.normal(size=(3, n)), rng.normal(size=(2, 4 * n)), rng.normal(size=(3, 2)), 0.7
    before = [A.copy(), Bs.copy(), C.copy()]
    y, z = calls.call_many(f, n, (A, Bs, C, s), per_run=(0, 1), n_threads=n_threads)
    y_ref, z_ref = _plain(f, A, Bs, C, s)
    assert y.shape == (2, n) and z.shape == (3, n)
    np.testing.assert_array_equal(y, y_ref)
    np.testing.assert_array_equal(z, z_ref)
    for a, b in zip((A, Bs, C), before):  # inputs are read, never written
        np.testing.assert_array_equal(a, b)


def test_call_many_memory_orders_give_the_same_runs(f):
    """C- or Fortran-ordered shared inputs, 1 or 2 threads: the same numbers, as computed by hand."""
    n = 5
    A = np.asfortranarray(np.arange(3 * n, dtype=float).reshape(3, n))
    Bs = np.ones((2, 4 * n), order="F")
    y1, _ = calls.call_many(f, n, (A, Bs, np.eye(3, 2), 2.0), per_run=(0, 1), n_threads=2)
    y2, _ = calls.call_many(f, n, (A, Bs, np.asfortranarray(np.eye(3, 2)), 2.0), per_run=(0, 1), n_threads=1)
    np.testing.assert_array_equal(y1, y2)
    np.testing.assert_array_equal(y1[0], 2.0 * A[0] + 4.0)


def test_call_many_bad_input_is_one_line(f):
    with pytest.raises(ValueError, match="expected 4 inputs"):
        calls.call_many(f, 2, (np.zeros((3, 2)),), per_run=(0,))
    with pytest.raises(ValueError, match=r"expected an array of shape \(3, 6\)"):
        calls.call_many(f, 6, (np.zeros((3, 2)), np.zeros((2, 24)), np.zeros((3, 2)), 1.0), per_run=(0, 1))
    with pytest.raises(ValueError, match="n must be a positive integer"):
        calls.call_many(f, 0, (np.zeros((3, 0)), np.zeros((2, 0)), np.zeros((3, 2)), 1.0), per_run=(0, 1))


@pytest.fixture(scope="module")
def f_loop(f, tmp_path_factory):
    """``f`` compiled with codegen.batch_loop_c's loops in its library (as the run functions are)."""
    import os

    from arvcas.build import codegen

    old = os.environ.get("ARVCAS_CACHE")
    os.environ["ARVCAS_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    try:
        g = codegen.build_described("f", "test_calls f, 3 + 8 + 6 + 1 inputs", lambda: f, batch_loop=True)
    finally:
        if old is None:
            os.environ.pop("ARVCAS_CACHE")
        else:
            os.environ["ARVCAS_CACHE"] = old
    return g


@pytest.mark.parametrize("n_threads", [1, 2, 3, 16])
def test_call_many_through_the_library_loop_equals_its_single_calls(f_loop, n_threads):
    """A library with the batch loop is evaluated by it (one ctypes call per thread, runs from a shared
    counter): every run equals CasADi's own call of the same compiled function, bit for bit."""
    assert calls.batch_loop(f_loop) is not None
    rng = np.random.default_rng(2)
    n = 13
    A, Bs, C, s = rng.normal(size=(3, n)), rng.normal(size=(2, 4 * n)), rng.normal(size=(3, 2)), -1.3
    y, z = calls.call_many(f_loop, n, (A, Bs, C, s), per_run=(0, 1), n_threads=n_threads)
    y_ref, z_ref = _plain(f_loop, A, Bs, C, s)
    np.testing.assert_array_equal(y, y_ref)
    np.testing.assert_array_equal(z, z_ref)
    (y1,) = calls.call_many(f_loop, n, (A, Bs, C, s), per_run=(0, 1), n_threads=1)[:1]
    np.testing.assert_array_equal(y1, y)
