"""ArduSub's own controller: the stabilise / depth-hold (ALT_HOLD) cascade and the vectored-6DOF mixer, as
ArduSub runs them, at its own loop rate inside arvcas's sample (docs/ardusub.md).

Read from ArduPilot's source (GPLv3; arvcas's own code, nothing copied; files and commits in
``arvcas/data/ardusub_params.toml`` and docs/ardusub.md):

* attitude (AC_AttitudeControl, _Sub): body-frame angle error to a rate target through the angle P
  (``ATC_ANG_*_P``), then a rate PID per axis (AC_PID: target filter FLTT, error filter FLTE, the error's
  derivative filtered by FLTD, integrator clipped to IMAX and frozen while the output is limited, P, I, D and
  feed-forward FF on the filtered target) to the roll, pitch and yaw inputs of the mixer (-1..1);
* depth (AC_PosControl's vertical loops): depth error (cm, up) to a climb-rate target through ``PSC_POSZ_P``,
  climb-rate P (AC_PID_Basic, ``PSC_VELZ_P``, error filter 5 Hz) to an acceleration target (cm/s^2), the
  acceleration PID (AC_PID, ``PSC_ACCZ_*``, its integrator limit raised to hover x 1000) to the throttle
  ``0.5 + 0.001 x output``, low-passed at 2 Hz by the motors; ``2 (throttle - 0.5)`` is the mixer's throttle;
* the mixer (AP_Motors6DOF, vectored 6DOF): roll/pitch/throttle on the vertical motors and yaw/forward/
  lateral on the horizontal ones, each group normalised when it exceeds 1, clipped to -1..1, then
  ``PWM = 1500 + 400 x output`` clipped to ``MOT_PWM_MIN..MOT_PWM_MAX``;
* the PWM reaches arvcas's thrusters through their command map (the system's T200 table): each ArduSub motor
  is the system's thruster in the same place (front/rear, port/starboard, horizontal/vertical); where the
  thruster's direction in the system file is opposite to ArduSub's motor direction the PWM is mirrored about
  1500 (``MOT_n_DIRECTION = -1`` on that motor). The law's wrench is ``B`` times those thrusts; the loop's
  allocation returns the same wrench (docs/ardusub.md "Motors").

The law runs ``n = round(h x 400)`` updates of 1/400 s on each sample's held estimate (the autopilot's loop
between two of arvcas's samples); the last update's PWM is sent. Horizontal position is not held (ALT_HOLD has
no position sensor): forward and lateral inputs are zero. The set point is the run's reference ``y1`` in depth,
roll, pitch and yaw (the mode's hold point, reached by the same reference as every law).

Gain columns per DOF: ``ANG_P`` (outer P), ``RAT_P`` (inner P), ``RAT_I`` (the integrator that removes
steady error); the ArduSub parameter of each slot is :data:`SLOTS` (x and y: none, ALT_HOLD does not use
them; their entries are inert). Every other ArduSub parameter is held at ArduSub's default.
"""

from __future__ import annotations

import math
import tomllib
from importlib import resources

import casadi as ca

from arvcas.controllers.base import DOFS, Controller, ControllerError, Gain, register
from arvcas.model import thrusters
from arvcas.sim.signals import Signal

__all__ = ["ArduSub", "SLOTS", "params", "slot_names", "lowpass_alpha", "ac_pid", "FLT_EPSILON"]

FLT_EPSILON = 1.1920929e-07  # float32 epsilon: ArduPilot's is_zero / is_positive / is_negative thresholds
COLUMNS = ("ANG_P", "RAT_P", "RAT_I")
# (DOF, column) -> the ArduSub parameter of that slot of the gain vector
SLOTS = {
    ("z", "ANG_P"): "PSC_POSZ_P", ("z", "RAT_P"): "PSC_VELZ_P", ("z", "RAT_I"): "PSC_ACCZ_I",
    ("phi", "ANG_P"): "ATC_ANG_RLL_P", ("phi", "RAT_P"): "ATC_RAT_RLL_P", ("phi", "RAT_I"): "ATC_RAT_RLL_I",
    ("theta", "ANG_P"): "ATC_ANG_PIT_P", ("theta", "RAT_P"): "ATC_RAT_PIT_P", ("theta", "RAT_I"): "ATC_RAT_PIT_I",
    ("psi", "ANG_P"): "ATC_ANG_YAW_P", ("psi", "RAT_P"): "ATC_RAT_YAW_P", ("psi", "RAT_I"): "ATC_RAT_YAW_I",
}
INERT = 1.0  # the value of the x and y slots (no ArduSub parameter)
_AXES = (("phi", "RLL"), ("theta", "PIT"), ("psi", "YAW"))

_TABLE: dict = {}


def params() -> dict:
    """The shipped ArduSub parameter table (``arvcas/data/ardusub_params.toml``), read once."""
    if not _TABLE:
        with resources.files("arvcas").joinpath("data/ardusub_params.toml").open("rb") as f:
            _TABLE.update(tomllib.load(f))
    return _TABLE


def _p(name: str) -> float:
    return float(params()["param"][name]["default"])


def _c(name: str) -> float:
    return float(params()["constants"][name]["value"])


def slot_names() -> list[str | None]:
    """The ArduSub parameter of each entry of the flat gain vector (DOF by DOF, column order); None: inert."""
    return [SLOTS.get((d, c)) for d in DOFS for c in COLUMNS]


def lowpass_alpha(dt: float, hz: float) -> float:
    """The first-order low-pass coefficient ArduPilot's filters use (AP_Math calc_lowpass_alpha_dt):
    ``dt / (dt + 1 / (2 pi f))``, 1 (no filter) for a cut-off of 0."""
    if dt <= 0 or hz <= 0:
        return 1.0
    return dt / (dt + 1.0 / (2.0 * math.pi * hz))


def ac_pid(state, target, measurement, dt: float, g: dict, limit=0, reset=0):
    """One update of ArduPilot's AC_PID (``update_all`` with SMAX = PDMX = 0, as ArduSub's defaults), in CasADi.

    ``state = (target_f, error_f, derivative_f, integrator)``; ``g``: ``P, I, D, FF, IMAX, FLTT, FLTE, FLTD``
    (filters in Hz, fixed numbers; gains numbers or expressions); ``reset``: the first update (the filters
    start at the input, the derivative at 0). Returns ``(output P + I + D, feed-forward FF x target_f,
    next state)``. The integrator grows only while the output is not ``limit``-ed, or when it shrinks;
    a zero I gain empties it."""
    T, E, D, I = state
    aT, aE, aD = (lowpass_alpha(dt, g[k]) for k in ("FLTT", "FLTE", "FLTD"))
    T1 = T + aT * (target - T)
    E1 = E + aE * ((T1 - measurement) - E)
    D1 = D + aD * ((E1 - E) / dt - D)
    T1 = ca.if_else(reset, target, T1)
    E1 = ca.if_else(reset, target - measurement, E1)
    D1 = ca.if_else(reset, 0, D1)
    ki = g["I"]
    grow = ca.logic_or(ca.logic_not(limit), ca.logic_or(ca.logic_and(I >= FLT_EPSILON, E1 <= -FLT_EPSILON),
                                                        ca.logic_and(I <= -FLT_EPSILON, E1 >= FLT_EPSILON)))
    I1 = ca.if_else(grow, ca.fmin(ca.fmax(I + E1 * ki * dt, -g["IMAX"]), g["IMAX"]), I)
    I1 = ca.if_else(ca.fabs(ki) < FLT_EPSILON, 0, I1)
    out = E1 * g["P"] + I1 + D1 * g["D"]
    return out, T1 * g["FF"], (T1, E1, D1, I1)


def _rate_gains(axis: str, P, I) -> dict:
    pre = f"ATC_RAT_{axis}_"
    return {"P": P, "I": I, **{k: _p(pre + k) for k in ("D", "FF", "IMAX", "FLTT", "FLTE", "FLTD")}}


def _euler_to_body(eta, d_euler):
    """Body rates of the Euler-angle rates ``d_euler`` at attitude ``eta`` (ZYX): the body-frame angle error
    of a small Euler-angle error."""
    ph, th = eta[3], eta[4]
    sp, cp, st, ct = ca.sin(ph), ca.cos(ph), ca.sin(th), ca.cos(th)
    return ca.vertcat(d_euler[0] - st * d_euler[2],
                      cp * d_euler[1] + sp * ct * d_euler[2],
                      -sp * d_euler[1] + cp * ct * d_euler[2])


def mixer(roll, pitch, yaw, throttle, forward=0, lateral=0):
    """AP_Motors6DOF's vectored-6DOF mix: the eight motor outputs (-1..1) in ArduSub's motor order."""
    F = params()["frame"]["vectored_6dof"]["factors"]
    rpt = [roll * f[0] + pitch * f[1] + throttle * f[3] for f in F]
    yfl = [yaw * f[2] + forward * f[4] + lateral * f[5] for f in F]
    rpt_max = ca.fmax(1, ca.mmax(ca.fabs(ca.vertcat(*rpt))))
    yfl_max = ca.fmax(1, ca.mmax(ca.fabs(ca.vertcat(*yfl))))
    return ca.vertcat(*[ca.fmin(ca.fmax(r / rpt_max + y / yfl_max, -1), 1) for r, y in zip(rpt, yfl)])


def motor_of_thruster(P):
    """For each of the system's thrusters: ``(weights (8,), sign)``: the one-hot selection of the ArduSub motor
    in its place (front/rear, port/starboard, horizontal/vertical; expressions of the parameters) and the sign
    of its direction against that motor's (+1 along, -1 opposite: the PWM is mirrored about 1500)."""
    fr = params()["frame"]["vectored_6dof"]
    out = []
    for n in P.s.thrusters:
        x, y = P[f"thrusters.{n}.position.x"], P[f"thrusters.{n}.position.y"]
        d = ca.vertcat(*[P[f"thrusters.{n}.direction.{c}"] for c in "xyz"])
        vert = ca.fabs(d[2]) > 0.5
        w, a = [], 0
        for f, (qx, qy), v in zip(fr["factors"], fr["quadrant"], fr["vertical"]):
            hit = ca.logic_and(ca.logic_and(ca.sign(x) == qx, ca.sign(y) == qy), vert if v else ca.logic_not(vert))
            w.append(hit)
            # the motor's direction for a positive output: verticals push down for a positive output
            # (throttle factor -1 raises); horizontals along (forward, lateral) factors
            dir_m = ca.vertcat(0, 0, -f[3]) if v else ca.vertcat(f[4], f[5], 0) / math.sqrt(f[4] ** 2 + f[5] ** 2)
            a = a + hit * dir_m
        out.append((ca.vertcat(*w), ca.sign(ca.dot(d, a))))
    return out


class ArduSub(Controller):
    name = "ardusub"
    label = "ArduSub"
    color = "tab:cyan"
    description = ("ArduSub's ALT_HOLD: angle P to rate PID, depth P-PI cascade, vectored-6DOF mixer to PWM "
                   "(its gains are ArduSub parameters: docs/ardusub.md)")
    gains = (
        Gain("ANG_P", "1/s", "outer P: ATC_ANG_RLL_P / _PIT_P / _YAW_P (angle to rate), PSC_POSZ_P (depth to climb "
                             "rate); x, y: inert"),
        Gain("RAT_P", "1/(rad/s), 1/s", "inner P: ATC_RAT_RLL_P / _PIT_P / _YAW_P, PSC_VELZ_P; x, y: inert"),
        Gain("RAT_I", "1/rad, 1/(cm/s)", "integrator: ATC_RAT_RLL_I / _PIT_I / _YAW_I, PSC_ACCZ_I; x, y: inert"),
    )
    defaults_block = "ardusub"
    state = (("att", 12), ("velz", 1), ("accz", 4), ("thr", 1), ("vz_prev", 1))
    signals = (
        Signal("pwm", "thrusters", "us", "", "", "PWM sent to each thruster by ArduSub's mixer (the system's thruster "
               "order; mirrored about 1500 where its direction is opposite to ArduSub's motor)", lambda c: c.out["pwm"]),
    )

    @property
    def defaults(self):
        return [(_p(SLOTS[(d, c)]) if (d, c) in SLOTS else INERT) for d in DOFS for c in COLUMNS]

    def _check(self, P):
        s = P.s
        if s.thrusters is None or len(s.thrusters) != 8 or s.thruster_dynamics is None:
            raise ControllerError(f"controller ardusub: system '{s.name}' needs eight listed thrusters with command "
                                  "maps (ArduSub's vectored-6DOF frame, e.g. bluerov2_heavy_alpha5); got "
                                  f"{0 if s.thrusters is None else len(s.thrusters)}")
        bad = [m.name for m in thrusters.thruster_maps(P) if m.unit != "us"]
        if bad:
            raise ControllerError(f"controller ardusub: system '{s.name}': thruster maps {bad} do not take PWM "
                                  "(unit 'us'); ArduSub's mixer sends PWM")

    def initial(self, ctx, G):
        return {"att": ca.DM.zeros(12), "velz": ca.DM.zeros(1), "accz": ca.DM.zeros(4),
                "thr": ca.DM(_c("throttle_hover")), "vz_prev": ctx.eta_dot_hat[2]}

    def step(self, ctx, G, x):
        P = ctx.P
        self._check(P)
        h = ctx.h
        n = max(1, int(round(h * _c("loop_rate"))))
        dt = h / n
        eta, ref = ctx.eta_hat, ctx.eta_ref
        # held over the sample: the angle error (body frame), the rates, depth and climb rate (cm, up)
        d_eu = ca.vertcat(ref[3] - eta[3], ref[4] - eta[4], ca.atan2(ca.sin(ref[5] - eta[5]), ca.cos(ref[5] - eta[5])))
        err_b = _euler_to_body(eta, d_eu)
        gyro = ctx.nu_hat[3:6]
        pos_err_cm = -100.0 * (ref[2] - eta[2])
        vel_up = -100.0 * ctx.eta_dot_hat[2]
        acc_up = -100.0 * (ctx.eta_dot_hat[2] - x["vz_prev"]) / h  # the estimate's climb acceleration over the sample
        rate_g = [_rate_gains(ax, G["RAT_P"][3 + i], G["RAT_I"][3 + i]) for i, (_, ax) in enumerate(_AXES)]
        accz_g = {"P": _p("PSC_ACCZ_P"), "I": G["RAT_I"][2], "D": _p("PSC_ACCZ_D"), "FF": 0.0,
                  "IMAX": max(_p("PSC_ACCZ_IMAX"), 1000.0 * _c("throttle_hover")),
                  "FLTT": 0.0, "FLTE": _p("PSC_ACCZ_FLTE"), "FLTD": 0.0}
        a_velz = lowpass_alpha(dt, _p("PSC_VELZ_FLTE"))
        a_thr = lowpass_alpha(dt, _c("throttle_filter"))
        hover = _c("throttle_hover")
        att = [tuple(x["att"][4 * i + j] for j in range(4)) for i in range(3)]
        velz, accz, thr = x["velz"], tuple(x["accz"][j] for j in range(4)), x["thr"]
        for k in range(n):
            reset = ctx.first if k == 0 else 0
            rpy = []
            for i in range(3):
                target = G["ANG_P"][3 + i] * err_b[i]
                out, ff, att[i] = ac_pid(att[i], target, gyro[i], dt, rate_g[i], 0, reset)
                rpy.append(out + ff)
            vel_target = G["ANG_P"][2] * pos_err_cm
            velz = ca.if_else(reset, vel_target - vel_up, velz + a_velz * ((vel_target - vel_up) - velz))
            acc_target = G["RAT_P"][2] * velz
            limited = ca.fabs(2 * (thr - hover)) >= 1
            out, _, accz = ac_pid(accz, acc_target, acc_up, dt, accz_g, limited, reset)
            thr = thr + a_thr * ((hover + 0.001 * out) - thr)
        throttle = ca.fmin(ca.fmax(2 * (thr - hover), -1), 1)
        motors = mixer(rpy[0], rpy[1], rpy[2], throttle)
        lo, hi = _p("MOT_PWM_MIN"), _p("MOT_PWM_MAX")
        mid, gain = _c("pwm_mid"), _c("pwm_per_output")
        pwm, u, tables = [], [], {}
        for (w, sgn), m in zip(motor_of_thruster(P), thrusters.thruster_maps(P)):
            c = ca.fmin(ca.fmax(mid + gain * sgn * ca.dot(w, motors), lo), hi)
            pwm.append(c)
            if m.name not in tables:  # one table (its slopes and jumps) per map, shared by its thrusters
                tables[m.name] = thrusters.pchip_powers(*thrusters.map_table(P, m))
            u.append(tables[m.name](thrusters.state_of(P, m, c)))
        u = ca.vertcat(*u)
        ctx.out["pwm"] = ca.vertcat(*pwm)
        tau_v = ca.mtimes(thrusters.B_T(P), u)
        nxt = {"att": ca.vertcat(*[v for a in att for v in a]), "velz": velz, "accz": ca.vertcat(*accz),
               "thr": thr, "vz_prev": ctx.eta_dot_hat[2]}
        return tau_v, nxt


register(ArduSub())
