"""Fluid loads on the manipulator's links: buoyancy and cross-flow drag by Gauss-Legendre quadrature.

Drag (paper eq. 9, generalised by docs/model.md §3): along the link axis ``u`` (unit vector of ``s_i``),
``f = -1/2 rho C_d D int_0^L |v_n(x)| v_n(x) dx`` and its moment about the frame origin
``n = -1/2 rho C_d D int_0^L (x u) x (|v_n(x)| v_n(x)) dx``, with ``v(x) = v_i + w_i x (x u)`` and
``v_n = v - (v.u) u``. ``D`` is the diameter (the paper's "cross-sectional area" is a slip, docs/model.md §3).
"""

from __future__ import annotations

import tomllib
from functools import lru_cache
from importlib import resources

import casadi as ca
import numpy as np

__all__ = ["gauss_legendre", "leggauss", "MAX_NODES", "link_drag", "normal_basis", "planar_drag", "buoyancy_force"]

MAX_NODES = 64  # the largest rule arvcas/data/gauss_legendre.toml holds
_TABLE = "data/gauss_legendre.toml"


@lru_cache(maxsize=None)
def _table() -> dict:
    with resources.files("arvcas").joinpath(_TABLE).open("rb") as f:
        return tomllib.load(f)


@lru_cache(maxsize=None)
def leggauss(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of the n-point Gauss-Legendre rule on [-1, 1], as ``numpy.polynomial.legendre.leggauss(n)``
    gives them: for n up to :data:`MAX_NODES` (every rule a run uses: ``ModelOptions.n_quad`` and
    ``time.thrust_quadrature`` stay within it) from ``arvcas/data/gauss_legendre.toml``, a table, so that a run's
    arithmetic (and the run digest of a committed front) does not depend on the NumPy release installed
    (leggauss's last bits differ between releases); beyond it, NumPy's own. Read-only arrays."""
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ValueError(f"n_quad: number of quadrature points must be an integer >= 1, got {n!r}")
    if n > MAX_NODES:
        x, w = np.polynomial.legendre.leggauss(n)
    else:
        rule = _table()[f"n{n}"]
        x, w = np.array(rule["x"], dtype=float), np.array(rule["w"], dtype=float)
    x.flags.writeable = w.flags.writeable = False
    return x, w


@lru_cache(maxsize=None)
def gauss_legendre(n: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Nodes and weights of the n-point Gauss-Legendre rule on [0, 1] (exact for degree 2n-1; :func:`leggauss`)."""
    xi, wi = leggauss(n)
    return tuple(0.5 * (xi + 1.0)), tuple(0.5 * wi)


def leggauss_table_text() -> str:
    """The text of ``arvcas/data/gauss_legendre.toml`` from the installed NumPy's leggauss (how it was written:
    ``python -c "from arvcas.model.hydro import leggauss_table_text as t; print(t(), end='')"``)."""
    out = [
        "# Gauss-Legendre rules on [-1, 1]: nodes x and weights w of the n-point rule, n = 1..64, for the arm's link",
        "# drag (ModelOptions.n_quad, arvcas.model.hydro) and the thrusters' forcing within a plant step",
        "# (time.thrust_quadrature, arvcas.sim.thrust_forcing). Dimensionless.",
        f"# Source: numpy.polynomial.legendre.leggauss(n) of NumPy {np.__version__} (arvcas.model.hydro.leggauss_table_text),",
        "# each value in its shortest round-trip form (read back exactly). Kept as data because leggauss's last bits",
        "# differ between NumPy releases (1.24.0 against 2.4.6), which changed every run's generated C and so the run",
        "# digests of the committed fronts (docs/provenance.md). tests/test_hydro.py checks the rules' exactness and",
        "# the table against the installed NumPy's leggauss.",
    ]
    for n in range(1, MAX_NODES + 1):
        x, w = np.polynomial.legendre.leggauss(n)
        out += ["", f"[n{n}]", f"x = [{', '.join(repr(float(v)) for v in x)}]", f"w = [{', '.join(repr(float(v)) for v in w)}]"]
    return "\n".join(out) + "\n"


def link_drag(rho, Cd, diameter, s, v, w, n_quad: int):
    """Drag force and moment (about the link frame's origin) on a cylinder along ``s``, in the link frame.

    ``v``: velocity of the frame origin, ``w``: angular velocity, both in the link frame, through still water.
    The normal velocity is affine along the axis: ``v_n(x) = a + x b`` with ``a = v - (v.u) u`` and
    ``b = w x u`` (already normal to u), and the moment is ``u x int x |v_n| v_n dx``.
    """
    L = ca.norm_2(s)
    u = s / L
    a = v - ca.dot(v, u) * u
    b = ca.cross(w, u)
    f, m = _drag_quadrature(L, a, b, n_quad)
    k = -0.5 * rho * Cd * diameter
    return k * f, k * ca.cross(u, m)


def normal_basis(u):
    """Unit vectors (e1, e2) with (u, e1, e2) right-handed and orthonormal, for a unit vector ``u``.

    ``e1`` is u x (the coordinate axis least aligned with u), normalised; ``e2 = u x e1``. Works on
    symbolic ``u`` (the choice is an ``if_else``).
    """
    ax, ay, az = ca.fabs(u[0]), ca.fabs(u[1]), ca.fabs(u[2])
    use_x = ca.logic_and(ax <= ay, ax <= az)
    use_y = ca.logic_and(ca.logic_not(use_x), ay <= az)
    c = ca.vertcat(ca.if_else(use_x, 1, 0), ca.if_else(use_y, 1, 0),
                   ca.if_else(ca.logic_or(use_x, use_y), 0, 1))
    e1 = ca.cross(u, c)
    e1 = e1 / ca.norm_2(e1)
    return e1, ca.cross(u, e1)


def planar_drag(k, L, a, b, n_quad: int):
    """The drag integrals of :func:`link_drag` in a basis (e1, e2) of the plane normal to the link.

    ``a``, ``b``: the 2 components of ``v_n(x) = a + x b`` in that basis; ``k = -1/2 rho C_d D``.
    Returns the force's components ``k int |v_n| v_n dx`` and the components ``k int x |v_n| v_n dx``
    whose cross product with ``u`` is the moment about the link origin:
    ``f = f1 e1 + f2 e2``, ``n = m1 e2 - m2 e1``.
    """
    f, m = _drag_quadrature(L, a, b, n_quad)
    return k * f, k * m


def _drag_quadrature(L, a, b, n_quad: int):
    """Gauss-Legendre sums ``int_0^L |v_n| v_n dx`` and ``int_0^L x |v_n| v_n dx``, ``v_n(x) = a + x b``."""
    nodes, weights = gauss_legendre(n_quad)
    f = 0
    m = 0
    for xi, wi in zip(nodes, weights):
        x = L * xi
        vn = a + x * b
        q = (wi * L) * ca.norm_2(vn) * vn
        f = f + q
        m = m + x * q
    return f, m


def buoyancy_force(rho, volume, g_i):
    """Buoyancy of a submerged volume: -rho V g (opposes gravity ``g_i``, expressed in the same frame)."""
    return -rho * volume * g_i
