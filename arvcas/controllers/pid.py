"""A per-DOF PID baseline, as ArduSub-style autopilots run: PID on the EKF estimate's error to the
reference, with feed-forward of the restoring forces, through the same allocation and saturation.

Per DOF in {n}, with ``e = eta_hat - y1``, ``e_dot = eta_dot_hat - y2`` and the integral state
``ie`` (``ie(k+1) = ie(k) + h e(k)``, explicit Euler like the other laws):

    tau_eta = Mhat (-kp e - ki ie - kd e_dot)
    tau_v   = J(eta_hat)^T tau_eta + g_n(eta_hat)

The gains are accelerations per unit error (so one set suits every DOF's inertia): kp in 1/s^2, ki in
1/s^3, kd in 1/s. ``g_n = a_g g(eta_hat)``: the restoring forces (weight and buoyancy, App. A) known
to the same fraction ``a_g`` as the AGSTA's nominal model (the scenario's ``uncertainty.g_factor``).
There is no anti-windup: the integral keeps growing while a thruster saturates (a known limit of
plain PID, visible in the results if the gains ask for more thrust than there is).

Default gains (``arvcas/data/gains.toml``, block ``pid``) come from one rule: the error dynamics of
the nominal double integrator, ``s^3 + kd s^2 + kp s + ki``, with a triple pole at ``-omega_c``:
``kd = 3 omega_c``, ``kp = 3 omega_c^2``, ``ki = omega_c^3``, ``omega_c = 0.5 rad/s`` in every DOF
(about the bandwidth of the ATD reference's 5 s transient).
"""

from __future__ import annotations

import casadi as ca

from arvcas.controllers.base import Controller, Gain, register
from arvcas.model import vehicle
from arvcas.model.spatial import J
from arvcas.sim.signals import DOFS, Signal

__all__ = ["PID"]


class PID(Controller):
    name = "pid"
    description = "per-DOF PID with restoring-force feed-forward (ArduSub-style baseline)"
    gains = (
        Gain("kp", "1/s^2", "proportional gain, acceleration per unit error"),
        Gain("ki", "1/s^3", "integral gain, acceleration per unit integrated error"),
        Gain("kd", "1/s", "derivative gain, acceleration per unit error rate"),
    )
    defaults_block = "pid"
    state = (("ie", 6),)
    signals = (
        Signal("ie", 6, "m s, m s, m s, rad s, rad s, rad s", "{n}", DOFS, "integral of the error e = eta_hat - y1",
               lambda c: c.out["ie"]),
    )

    def initial(self, ctx, G):
        return {"ie": ca.DM.zeros(6)}

    def step(self, ctx, G, x):
        ie = x["ie"]
        tau_eta = ctx.Mhat * (-G["kp"] * ctx.e - G["ki"] * ie - G["kd"] * ctx.e_dot)
        tau_v = ca.mtimes(J(ctx.eta_hat).T, tau_eta) + ctx.unc[2] * vehicle.g_vec(ctx.P, ctx.eta_hat)
        ctx.out["ie"] = ie
        return tau_v, {"ie": ie + ctx.h * ctx.e}


register(PID())
