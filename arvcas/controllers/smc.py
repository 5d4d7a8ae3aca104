"""The sliding-mode family of section 3: GSTA on the sliding variable, an adaptive gain law, and a
compensation of the total disturbance (the RESO, or a nominal model).

Per DOF of eta in {n}, with the reference's errors ``e = eta_hat - y1`` and ``e_dot = eta_dot_hat - y2``
(see :class:`arvcas.sim.closedloop.StepContext`):

1. ``s = e_dot + c e`` (eq. 17);
2. the GSTA output ``v`` and its integral state ``w`` (eq. 18, 21; explicit Euler, or the implicit
   step of docs/model.md §5b), with ``k2`` from ``k1`` (eq. 19);
3. ``tau_eta`` from the compensation: :class:`RESOCompensation` (eq. 14-16, 20) or
   :class:`NominalCompensation` (the AGSTA baseline, docs/model.md §5);
4. ``tau_v = J(eta_hat)^T tau_eta`` (eq. 20); ``k1`` for the next sample from the law.

A concrete controller (:mod:`.proposed`, :mod:`.agsta`, :mod:`.traditional`, :mod:`.implicit`)
chooses the step, the law and the compensation, and declares its gain columns.
"""

from __future__ import annotations

import casadi as ca

from arvcas.controllers import gsta, reso
from arvcas.controllers.base import Controller, Gain
from arvcas.model import vehicle
from arvcas.model.spatial import J, J_dot, J_inv
from arvcas.sim.signals import DOFS, RATE_UNITS, WRENCH_UNITS, Signal

__all__ = ["SlidingMode", "RESOCompensation", "NominalCompensation", "SMC_SIGNALS", "G_SURFACE", "G_GSTA",
           "G_ADAPT"]

_K_NOTE = "dimensionless as the gains file gives it; k1 phi1(s) of eq. 21 is an acceleration (m/s^2, rad/s^2)"

SMC_SIGNALS = (
    Signal("s", 6, RATE_UNITS, "{n}", DOFS, "sliding variable s = e_dot + c e (eq. 17), e = eta_hat - y1",
           lambda c: c.out["s"]),
    Signal("k1", 6, "1", "", DOFS, "adaptive gain k1 (eq. 19): " + _K_NOTE, lambda c: c.out["k1"]),
    Signal("k2", 6, "1", "", DOFS, "gain k2 = 2 eps k1 + beta + 4 eps^2 (eq. 19): " + _K_NOTE,
           lambda c: c.out["k2"]),
    Signal("f_hat", 6, WRENCH_UNITS, "{n}", DOFS,
           "controller's total-disturbance estimate in force units: Mhat z2 of the RESO, or -f_n of the nominal model",
           lambda c: c.out["f_hat"]),
)

G_SURFACE = Gain("c", "1/s", "sliding-surface slope of s = e_dot + c e (eq. 17)")
G_GSTA = (
    Gain("mu1", "(m/s)^(1/2) or (rad/s)^(1/2) per unit s", "weight of |s|^(1/2) sgn(s) in phi1 (eq. 18)"),
    Gain("mu2", "1", "weight of s in phi1 (eq. 18)"),
)
G_ADAPT = {
    "l": Gain("l", "1/s", "growth rate of k1 outside the neighbourhood |s| > sigma (eq. 19)"),
    "r": Gain("r", "1/s", "decay rate of k1 inside the neighbourhood (eq. 19)"),
    "k1_0": Gain("k1_0", "1", "initial value of k1"),
    "k1min": Gain("k1min", "1", "floor of k1's decrease (eq. 19)"),
    "eps": Gain("eps", "1", "eps of k2 = 2 eps k1 + beta + 4 eps^2 (eq. 19)"),
    "beta": Gain("beta", "1", "beta of k2 (eq. 19)"),
    "sigma": Gain("sigma", "m/s or rad/s", "neighbourhood of s = 0 in which k1 stops growing (eq. 19)"),
}
G_OMEGA = Gain("omega", "rad/s", "RESO bandwidth: both observer poles at -omega (eq. 16, docs/model.md §5)",
               upper_of_h=lambda h: 2.0 / h)


class RESOCompensation:
    """The reduced-order ESO (eq. 14-16): ``tau_eta = Mhat (-c e_dot - z2 + v)`` (eq. 20, docs/model.md §5)."""

    state = (("z1", 6), ("z2", 6), ("tau_eta_prev", 6))

    def initial(self, ctx, G):
        return {"z1": ctx.eta_dot_hat, "z2": ca.DM.zeros(6), "tau_eta_prev": ca.DM.zeros(6)}

    def tau_eta(self, ctx, G, x, v):
        beta1, beta2 = reso.reso_gains(G["omega"])
        z1, z2 = reso.reso_step(x["z1"], x["z2"], ctx.eta_dot_hat, x["tau_eta_prev"], 1 / ctx.Mhat, beta1, beta2,
                                ctx.h)
        tau_eta = ctx.Mhat * (-G["c"] * ctx.e_dot - z2 + v)
        return tau_eta, ctx.Mhat * z2, {"z1": z1, "z2": z2, "tau_eta_prev": tau_eta}


class NominalCompensation:
    """The AGSTA baseline's nominal model: ``tau_eta = Mhat (-c e_dot + v) + f_n`` (docs/model.md §5).

    ``f_n = J^-T (C_n nu - M J^-1 Jdot nu + D_n nu + g_n - a (tau_m + trim))`` with the scenario's
    nominal factors ``unc = [C, D, g, arm]`` and the true arm wrench at this sample (the baseline knows
    a fraction of it).
    """

    state = ()

    def initial(self, ctx, G):
        return {}

    def tau_eta(self, ctx, G, x, v):
        P, unc, eta, nu = ctx.P, ctx.unc, ctx.eta_hat, ctx.nu_hat
        Ji = J_inv(eta)
        eta_dot = ca.mtimes(J(eta), nu)
        Jdot_nu = ca.mtimes(J_dot(eta, eta_dot), nu)
        body = (
            unc[0] * ca.mtimes(vehicle.C_RB(P, nu), nu)
            - ca.mtimes(vehicle.M(P), ca.mtimes(Ji, Jdot_nu))
            + unc[1] * ca.mtimes(vehicle.D(P, nu), nu)
            + unc[2] * vehicle.g_vec(P, eta)
            - unc[3] * ctx.tau_arm
        )
        f_n = ca.mtimes(Ji.T, body)
        return ctx.Mhat * (-G["c"] * ctx.e_dot + v) + f_n, -f_n, {}


class SlidingModeController(Controller):
    """A GSTA controller of section 3; subclasses set ``compensation``, ``implicit`` and :meth:`k1_next`."""

    compensation = RESOCompensation()
    implicit = False
    signals = SMC_SIGNALS

    @property
    def state(self):  # noqa: D401 - the GSTA's state, then the compensation's
        return (("w", 6), ("k1", 6)) + tuple(self.compensation.state)

    def initial(self, ctx, G):
        return {"w": ca.DM.zeros(6), "k1": G["k1_0"], **self.compensation.initial(ctx, G)}

    def k1_next(self, G, k1, s, h):
        raise NotImplementedError

    def step(self, ctx, G, x):
        s = ctx.e_dot + G["c"] * ctx.e  # eq. 17
        k1 = x["k1"]
        k2 = gsta.k2_of_k1(k1, G["eps"], G["beta"])  # eq. 19
        law = gsta.gsta_implicit if self.implicit else gsta.gsta_explicit  # docs/model.md §5b / eq. 21
        v, w_next = law(s, x["w"], k1, k2, G["mu1"], G["mu2"], ctx.h)
        tau_eta, f_hat, comp_next = self.compensation.tau_eta(ctx, G, x, v)
        tau_v = ca.mtimes(J(ctx.eta_hat).T, tau_eta)  # eq. 20
        ctx.out.update(s=s, k1=k1, k2=k2, f_hat=f_hat)
        return tau_v, {"w": w_next, "k1": self.k1_next(G, k1, s, ctx.h), **comp_next}


SlidingMode = SlidingModeController
