"""arvcas.dynamics: the compiled plant functions and Jacobians on NumPy arrays.

References: CasADi's VM evaluating the same SX graphs (independent of the compiled C and of the
batch loop), and central finite differences of the compiled function for the Jacobians.
"""

from __future__ import annotations

import numpy as np
import pytest

import arvcas
from arvcas.build import dynamics as dyn
from arvcas.build.export import example_inputs
from arvcas.model import uvms
from arvcas.system.params import load

RTOL = 1e-12


def _vm(f, args):
    out = f.call([np.asarray(a, dtype=float) for a in args])
    return [np.asarray(o) for o in out]


def _inputs(f, rng, scale=0.1):
    """Example inputs of ``f`` (without p) perturbed by up to +-scale relative."""
    nominal = example_inputs()
    out = []
    for name in f.name_in()[:-1]:
        v = nominal[name]
        v = v * (1 + scale * rng.uniform(-1, 1, v.shape)) + 0.01 * rng.uniform(-1, 1, v.shape)
        out.append(np.clip(v, 0, 1) if name == "payload" else v)
    return out


@pytest.fixture(scope="module")
def sx():
    return dyn._sx(uvms.ModelOptions())


def _close(a, b, what):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, what
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * max(1.0, float(np.max(np.abs(b)))), err_msg=what)


@pytest.mark.parametrize("name", dyn.NAMES)
def test_single_call_matches_vm(name, sx):
    rng = np.random.default_rng(1)
    d = arvcas.dynamics(name)
    f = sx[name]
    p = load().vector()
    for _ in range(3):
        args = _inputs(f, rng)
        got = d(*args)
        ref = _vm(f, [*args, p])
        got = got if isinstance(got, tuple) else (got,)
        assert len(got) == f.n_out()
        for g, r, k in zip(got, ref, f.name_out()):
            assert type(g) is np.ndarray and g.dtype == np.float64
            assert g.shape == (r.shape[0],) if r.shape[1] == 1 else g.shape == r.shape
            _close(g, r.reshape(g.shape), f"{name}.{k}")


@pytest.mark.parametrize("name", ["vehicle_rhs", "uvms_rhs", "uvms_rhs_jac", "thrust"])
@pytest.mark.parametrize("n", [1, 7, 300])
def test_batch_matches_vm(name, n, sx):
    """Row i of a batch = the VM at row i; some inputs per row, the others shared (broadcast)."""
    rng = np.random.default_rng(n)
    d = arvcas.dynamics(name)
    f = sx[name]
    p = load().vector()
    rows = [_inputs(f, rng) for _ in range(n)]
    shared = _inputs(f, rng)
    per_row = [i % 2 == 0 for i in range(f.n_in() - 1)]  # x, q, qdd, ... per row; tau, qd, ... shared
    args = [np.array([r[i] for r in rows]) if per_row[i] else shared[i] for i in range(f.n_in() - 1)]
    got = d(*args)
    got = got if isinstance(got, tuple) else (got,)
    fm = f.map(n)
    ref = _vm(fm, [np.array([r[i] for r in rows]).T if per_row[i] else np.tile(shared[i][:, None], (1, n))
                   for i in range(f.n_in() - 1)] + [np.tile(p[:, None], (1, n))])
    for g, r, k in zip(got, ref, f.name_out()):
        rows_out = f.size1_out(f.index_out(k))
        cols = f.size2_out(f.index_out(k))
        if cols == 1:
            want = r.T  # (n, rows)
        else:
            want = np.stack([r[:, j * cols:(j + 1) * cols] for j in range(n)])
        assert g.shape == ((n, rows_out) if cols == 1 else (n, rows_out, cols))
        _close(g, want, f"{name}.{k} n={n}")


def test_batch_same_bits_on_any_thread_count_and_as_single_calls():
    rng = np.random.default_rng(5)
    d = arvcas.dynamics("uvms_rhs")
    n = 2 * dyn.THREAD_MIN_BATCH + 37
    fs = uvms.plant_functions()  # built once (a graph build per row cost minutes of CPU)
    args = [np.array(_inputs(fs["uvms_rhs"], rng)[i]) for i in range(6)]
    x = np.array([_inputs(fs["vehicle_rhs"], rng)[0] for _ in range(n)])
    a1 = d(x, *args[1:], n_threads=1)
    a2 = d(x, *args[1:], n_threads=2)
    a3 = d(x, *args[1:], n_threads=5)
    np.testing.assert_array_equal(a1, a2)
    np.testing.assert_array_equal(a1, a3)
    for i in (0, dyn.THREAD_MIN_BATCH, n - 1):
        np.testing.assert_array_equal(a1[i], d(x[i], *args[1:]))


def test_p_per_row_and_params():
    rng = np.random.default_rng(2)
    d = arvcas.dynamics("vehicle_rhs")
    f = uvms.plant_functions()["vehicle_rhs"]
    P = load()
    n = 300
    x = np.array([_inputs(f, rng)[0] for _ in range(n)])
    tau = _inputs(f, rng)[1]
    heavy = P.replace({"vehicle.m": P["vehicle.m"] * 1.3})
    ps = np.array([P.vector() if i % 2 else heavy.vector() for i in range(n)])
    got = d(x, tau, p=ps)
    for i in (0, 1, 255, 256, n - 1):
        _close(got[i], _vm(f, [x[i], tau, ps[i]])[0].ravel(), f"row {i}")
    np.testing.assert_array_equal(d(x[0], tau, params=heavy), d(x[0], tau, heavy.vector()))
    np.testing.assert_array_equal(d(x[1], tau), d(x[1], tau, p=P.vector()))
    assert not np.array_equal(d(x[0], tau, params=heavy), d(x[0], tau))
    # the p given last is not kept between calls: changing the caller's array changes the result
    pv = P.vector().copy()
    r0 = d(x[0], tau, p=pv)
    pv[P.names().index("vehicle.m")] *= 1.3
    np.testing.assert_array_equal(d(x[0], tau, p=pv), d(x[0], tau, params=heavy))
    assert not np.array_equal(r0, d(x[0], tau, p=pv))


def test_one_row_broadcasts_and_any_layout():
    """An input of one row is shared like one without the batch axis; any dtype, order or stride is read."""
    rng = np.random.default_rng(4)
    d = arvcas.dynamics("vehicle_rhs")
    f = uvms.plant_functions()["vehicle_rhs"]
    X = np.array([_inputs(f, rng)[0] for _ in range(300)])
    tau = _inputs(f, rng)[1]
    ref = d(X, tau)
    np.testing.assert_array_equal(d(X, tau[None, :]), ref)
    np.testing.assert_array_equal(d(X, tau, p=load().vector()[None, :]), ref)
    np.testing.assert_array_equal(d(np.asfortranarray(X), tau), ref)
    wide = np.zeros((300, 24))
    wide[:, ::2] = X
    np.testing.assert_array_equal(d(wide[:, ::2], tau), ref)
    np.testing.assert_array_equal(d(X[:1], tau[None, :]), ref[:1])
    assert d(X[:1], tau).shape == (1, 12)
    np.testing.assert_array_equal(d(np.zeros(12, dtype=int), [0, 0, 0, 0, 0, 0]), d(np.zeros(12), np.zeros(6)))


def test_scalar_payload_shapes():
    d = arvcas.dynamics("uvms_rhs")
    e = example_inputs()
    a = d(e["x"], e["tau"], e["q"], e["qd"], e["qdd"], 0.5)
    b = d(e["x"], e["tau"], e["q"], e["qd"], e["qdd"], [0.5])
    np.testing.assert_array_equal(a, b)
    c = d(e["x"], e["tau"], e["q"], e["qd"], e["qdd"], np.array([0.0, 0.5, 1.0]))
    assert c.shape == (3, 12)
    np.testing.assert_array_equal(c[1], a)
    np.testing.assert_array_equal(d(e["x"], e["tau"], e["q"], e["qd"], e["qdd"], [[0.0], [0.5], [1.0]]), c)


def test_errors_are_one_line():
    d = arvcas.dynamics("vehicle_rhs")
    x, tau = example_inputs()["x"], example_inputs()["tau"]
    cases = [
        (lambda: d(x[:11], tau), r"vehicle_rhs: x: expected shape \(12,\) or \(n, 12\), got \(11,\)"),
        (lambda: d(x.reshape(3, 4), tau), r"x: expected shape \(12,\) or \(n, 12\), got \(3, 4\)"),
        (lambda: d(np.zeros((4, 12)), np.zeros((5, 6))), r"batch sizes differ: tau has 5 rows, x has 4"),
        (lambda: d(x), r"expected 2 inputs \(x, tau\) and optionally p, got 1"),
        (lambda: d(x, tau, np.zeros(3)), r"p: expected shape \(140,\)"),
        (lambda: d(np.where(np.arange(12) == 4, np.nan, x), tau), r"x has a non-finite value nan at index \[4\]"),
        (lambda: d(x, np.where(np.arange(6) == 2, np.inf, tau)), r"tau has a non-finite value inf at index \[2\]"),
        (lambda: d(np.tile(x, (3, 1)), tau, p=np.where(np.arange(140) == 9, np.nan, 1.0)), r"p has a non-finite value nan"),
        (lambda: d(np.where(np.arange(24).reshape(2, 12) == 13, -np.inf, 1.0), tau), r"x has a non-finite value -inf at index \[1, 1\]"),
        (lambda: d(x, tau, p=load().vector(), params=load()), r"give p= or params=, not both"),
        (lambda: d(x, tau, params={"a": 1}), r"params: expected arvcas.system.params.Params, got dict"),
        (lambda: d(x, tau, n_threads=0), r"n_threads: expected a positive integer or None, got 0"),
        (lambda: d("abc", tau), r"x: expected numbers, got a str"),
        (lambda: arvcas.dynamics("uvms_rhs", system="bluerov2_hevy"), r"neither a shipped system .*did you mean 'bluerov2_heavy'"),
        (lambda: arvcas.dynamics("nope"), r"unknown function 'nope'; allowed: vehicle_rhs, arm_wrench, .*uvms_rhs_jac"),
    ]
    for call, msg in cases:
        with pytest.raises(ValueError, match=msg) as e:
            call()
        assert "\n" not in str(e.value), str(e.value)


def _fd_check(name, wrt, rng, h=1e-6, tol=1e-6):
    """Central differences of the compiled function against its Jacobian outputs.

    Truncation error ~ h^2 |f'''| and round-off ~ eps |f| / h are both below 1e-8 here; the tolerance
    is tol * (1 + max |J|) per column (1e-6).
    """
    base = arvcas.dynamics(name)
    jac = arvcas.dynamics(name + "_jac")
    f = uvms.plant_functions()[name]
    for _ in range(3):
        args = _inputs(f, rng, scale=0.3)
        outs = jac(*args)
        np.testing.assert_array_equal(outs[0], base(*args))
        for k, w in enumerate(wrt):
            i = f.name_in().index(w)
            J = outs[1 + k]
            assert J.shape == (12, f.numel_in(i))
            fd = np.empty_like(J)
            for j in range(J.shape[1]):
                step = h * max(1.0, abs(args[i][j]))
                up = [a.copy() for a in args]
                dn = [a.copy() for a in args]
                up[i][j] += step
                dn[i][j] -= step
                fd[:, j] = (base(*up) - base(*dn)) / (2 * step)
            scale = 1.0 + np.max(np.abs(J))
            assert np.max(np.abs(J - fd)) <= tol * scale, f"{name} d/d{w}: {np.max(np.abs(J - fd))}"
            assert np.max(np.abs(J)) > 0


def test_vehicle_jacobian_against_finite_differences():
    _fd_check("vehicle_rhs", ("x", "tau"), np.random.default_rng(11))


def test_uvms_jacobian_against_finite_differences():
    _fd_check("uvms_rhs", ("x", "tau", "q"), np.random.default_rng(12))


def test_jacobian_batch_layout():
    """Batched Jacobians: element [i, r, c] = d xdot_r / d x_c of row i (not transposed)."""
    rng = np.random.default_rng(3)
    jac = arvcas.dynamics("vehicle_rhs_jac")
    f = uvms.plant_functions()["vehicle_rhs"]
    rows = [_inputs(f, rng) for _ in range(5)]
    x = np.array([r[0] for r in rows])
    tau = np.array([r[1] for r in rows])
    xdot, A, B = jac(x, tau)
    for i in range(5):
        xi, Ai, Bi = jac(x[i], tau[i])
        np.testing.assert_array_equal(A[i], Ai)
        np.testing.assert_array_equal(B[i], Bi)
    # kinematic rows: d(eta_dot)/d(nu) = J(eta), so d xdot_0 / d u = cos(theta) cos(psi)
    th, ps = x[:, 4], x[:, 5]
    np.testing.assert_allclose(A[:, 0, 6], np.cos(th) * np.cos(ps), rtol=1e-14)
    np.testing.assert_array_equal(B[:, :6, :], 0.0)


def test_dynamics_repr_and_memo():
    d = arvcas.dynamics("uvms_rhs")
    assert d is arvcas.dynamics("uvms_rhs")
    assert d.input_names == ("x", "tau", "q", "qd", "qdd", "payload", "p")
    assert d.output_names == ("xdot",)
    assert "uvms_rhs(x[12]" in repr(d)
    assert arvcas.dynamics("uvms_rhs_jac").output_names == ("xdot", "dxdot_dx", "dxdot_dtau", "dxdot_dq")


def test_another_system_is_sized_by_it_and_defaults_to_its_parameters():
    """dynamics(name, system=): inputs sized by the system (q[4], u[8]), p its parameters; equal to compiled."""
    s = arvcas.load_system("bluerov2_heavy_alpha5")
    f = arvcas.dynamics("uvms_rhs", system=s)
    assert f.input_sizes == (12, 6, 4, 4, 4, 1, len(s.params))
    rng = np.random.default_rng(5)
    x, tau, q, qd, qdd = rng.normal(size=(8, 12)) * 0.1, rng.normal(size=(8, 6)), rng.normal(size=(8, 4)), \
        rng.normal(size=(8, 4)), rng.normal(size=(8, 4))
    got = f(x, tau, q, qd, qdd, 0.5)
    c = arvcas.compiled("uvms_rhs", system=s)
    for i in range(8):
        ref = np.array(c(x[i], tau[i], q[i], qd[i], qdd[i], 0.5, s.params.vector())).ravel()
        np.testing.assert_allclose(got[i], ref, rtol=1e-14, atol=1e-14)
    al = arvcas.dynamics("allocate", system="bluerov2_heavy_alpha5")
    assert al(np.eye(6)).shape == (6, 8)
    J = arvcas.dynamics("uvms_rhs_jac", system=s)(x[0], tau[0], q[0], qd[0], qdd[0], 0.5)
    assert J[0].shape == (12,) and J[1].shape == (12, 12) and J[3].shape == (12, 4)
