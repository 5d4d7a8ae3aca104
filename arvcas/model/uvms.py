"""The coupled vehicle + manipulator and the public plant functions as named CasADi SX Functions.

Inputs are dense columns with the parameter vector ``p`` (``Params.vector()``) last, so every model
number is a runtime input. The coupling is exact (docs/model.md §3): the arm's wrench is affine in the vehicle
acceleration, ``tau_m = tau_m0 - M_arm(q) nu_dot``, so the coupled vehicle solves
``(M + M_arm(q)) nu_dot = tau + tau_m0 + tau_trim - C nu - D nu - g`` with no lagged acceleration.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from arvcas.model import manipulator, thrusters, vehicle
from arvcas.model.hydro import MAX_NODES
from arvcas.model.linalg import lu_solve, solve_nopivot
from arvcas.model.spatial import J

__all__ = ["ModelOptions", "coupled_terms", "coupled_terms_scheduled", "coupled_accel", "uvms_xdot", "plant_functions", "PUBLIC_FUNCTIONS"]

PUBLIC_FUNCTIONS = ("vehicle_rhs", "arm_wrench", "uvms_rhs", "allocate", "thrust")


@dataclass(frozen=True)
class ModelOptions:
    """Build options: they change the graph's structure, so they are part of the compile-cache key."""

    n_quad: int = 5  # Gauss-Legendre points per link for the drag integral (docs/model.md §3)

    def __post_init__(self):
        if not isinstance(self.n_quad, int) or isinstance(self.n_quad, bool) or not 1 <= self.n_quad <= MAX_NODES:
            raise ValueError(f"ModelOptions.n_quad: must be an integer in [1, {MAX_NODES}], got {self.n_quad!r}")

    def tag(self) -> str:
        return f"nq{self.n_quad}"

    @classmethod
    def checked(cls, opts, what: str = "opts", error: type[Exception] = ValueError) -> "ModelOptions":
        """``opts`` itself, or the default options for ``None``; ``error`` (naming ``what``) for anything else."""
        if opts is None:
            return cls()
        if not isinstance(opts, cls):
            raise error(f"{what}: expected arvcas.model.uvms.ModelOptions, got {type(opts).__name__}")
        return opts


def coupled_terms(P, eta, nu, tau, q, qd, qdd, payload, tau_extra, opts: ModelOptions, current=None):
    """(nu_dot, tau_m) of the exactly coupled vehicle + arm (paper eq. 1 with eq. 11, docs/model.md §3).

    ``tau``: body wrench at the COB (thrust + disturbance); ``tau_extra``: further body wrench (the
    trim buoyancy of docs/model.md §3). ``tau_m`` is the arm's wrench on the vehicle at this acceleration.
    ``current``: ``(nu_c, nu_c_dot)`` of :func:`arvcas.model.water.relative_current` (docs/model.md §10).
    """
    v_c_b = None if current is None else current[0][0:3]
    tm0 = manipulator.arm_wrench(P, eta, nu, ca.DM.zeros(6), q, qd, qdd, payload, opts.n_quad, v_c_b)
    Mb = manipulator.base_inertia(P, q, payload)  # tau_m = tm0 - M_arm nu_dot, exact
    b = tau + tm0 + tau_extra - vehicle.forces(P, eta, nu, current)
    nud = solve_nopivot(vehicle.M(P) + Mb, b)  # M + M_arm is diagonally dominant
    return nud, tm0 - ca.mtimes(Mb, nud)


def coupled_terms_scheduled(P, eta, nu, tau, rec: dict, tau_extra, opts: ModelOptions, current=None):
    """:func:`coupled_terms` from a record of the run's time table (:func:`arvcas.sim.schedule.unpack`).

    The same equations: the arm's wrench from its time-only terms and the vehicle state
    (:func:`arvcas.model.manipulator.arm_wrench_scheduled`), and ``(M + M_arm) nu_dot = b`` by the tabulated
    LU factors. Equal to :func:`coupled_terms` to round-off.
    """
    v_c_b = None if current is None else current[0][0:3]
    tm0 = manipulator.arm_wrench_scheduled(P, rec, eta, nu, opts.n_quad, v_c_b)
    b = tau + tm0 + tau_extra - vehicle.forces(P, eta, nu, current)
    nud = lu_solve(*rec["lu"], b)
    return nud, tm0 - ca.mtimes(rec["M_arm"], nud)


def coupled_accel(P, eta, nu, tau, q, qd, qdd, payload, tau_extra, opts: ModelOptions, current=None):
    """nu_dot of the exactly coupled vehicle + arm (see :func:`coupled_terms`)."""
    return coupled_terms(P, eta, nu, tau, q, qd, qdd, payload, tau_extra, opts, current)[0]


def uvms_xdot(P, x, tau, q, qd, qdd, payload, opts: ModelOptions, trim=None, current=None):
    """xdot = [J(eta) nu; nu_dot] of the coupled system; ``trim`` defaults to docs/model.md §3 trim at q0;
    ``current``: ``(nu_c, nu_c_dot)`` (docs/model.md §10; the public ``uvms_rhs`` has none)."""
    eta, nu = x[0:6], x[6:12]
    if trim is None:
        trim = manipulator.trim_wrench(P, eta, opts.n_quad)
    nud = coupled_accel(P, eta, nu, tau, q, qd, qdd, payload, trim, opts, current)
    return ca.vertcat(ca.mtimes(J(eta), nu), nud)


def plant_functions(opts: ModelOptions = ModelOptions(), layout=None) -> dict[str, ca.Function]:
    """The public plant functions, as SX Functions, by their exact names and input orders.

    ``layout``: the system's :class:`arvcas.system.params.Layout` (default Haidou-1's); inputs are sized by it:
    ``q[n_joints]``, ``u[n_thrusters]``, ``p[n_params]``.
    """
    from arvcas.system.params import default_layout, view

    lay = layout or default_layout()
    p = ca.SX.sym("p", len(lay))
    P = view(p, lay)
    nj, nt = lay.structure.n_joints, lay.structure.n_thrusters
    x = ca.SX.sym("x", 12)
    tau = ca.SX.sym("tau", 6)
    eta, nu, nud = ca.SX.sym("eta", 6), ca.SX.sym("nu", 6), ca.SX.sym("nud", 6)
    q, qd, qdd = ca.SX.sym("q", nj), ca.SX.sym("qd", nj), ca.SX.sym("qdd", nj)
    payload = ca.SX.sym("payload", 1)
    u = ca.SX.sym("u", nt)

    fns = {
        "vehicle_rhs": ca.Function(
            "vehicle_rhs", [x, tau, p], [vehicle.rhs(P, x, tau)], ["x", "tau", "p"], ["xdot"]
        ),
        "arm_wrench": ca.Function(
            "arm_wrench",
            [eta, nu, nud, q, qd, qdd, payload, p],
            [manipulator.arm_wrench(P, eta, nu, nud, q, qd, qdd, payload, opts.n_quad)],
            ["eta", "nu", "nud", "q", "qd", "qdd", "payload", "p"],
            ["tau_m"],
        ),
        "uvms_rhs": ca.Function(
            "uvms_rhs",
            [x, tau, q, qd, qdd, payload, p],
            [uvms_xdot(P, x, tau, q, qd, qdd, payload, opts)],
            ["x", "tau", "q", "qd", "qdd", "payload", "p"],
            ["xdot"],
        ),
        "allocate": ca.Function("allocate", [tau, p], [thrusters.allocate(P, tau)], ["tau", "p"], ["u"]),
        "thrust": ca.Function("thrust", [u, p], [thrusters.thrust(P, u)], ["u", "p"], ["tau"]),
    }
    return fns
