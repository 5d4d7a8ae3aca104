"""ArduSub's controller (arvcas/controllers/ardusub.py, docs/ardusub.md): its registry entry and parameters, the
AC_PID replica against ArduPilot's own AC_PID compiled outside the repository (tests/data/
ardusub_ac_pid_reference.csv, provenance in its header), the mixer and the motor mapping on the BlueROV2 Heavy,
the .param export, and a closed-loop depth / attitude hold."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

import arvcas
from arvcas.cli import main
from arvcas.controllers import ardusub, gains as gains_mod, names
from arvcas.io import ardusub_params as ap
from arvcas.system.params import view

REF = Path(__file__).parent / "data" / "ardusub_ac_pid_reference.csv"
CASES = {  # P I D FF IMAX FLTT FLTE FLTD (PDMX 0, dt 0.0025): the table's header
    "roll_rate_defaults": (0.135, 0.090, 0.0036, 0.0, 0.444, 30.0, 0.0, 30.0),
    "yaw_rate_defaults": (0.180, 0.018, 0.0, 0.0, 0.222, 5.0, 0.0, 5.0),
    "accel_z_defaults": (0.5, 0.1, 0.0, 0.0, 500.0, 0.0, 20.0, 0.0),
    "all_filters_ff_imax": (0.3, 2.0, 0.01, 0.2, 0.05, 10.0, 15.0, 20.0),
}


def test_registered_with_ardusub_names_defaults_and_ranges():
    assert "ardusub" in names()
    table = ardusub.params()["param"]
    slots = ardusub.slot_names()
    g0 = gains_mod.default_gains("ardusub")
    assert len(slots) == gains_mod.n_gains("ardusub") == g0.size
    named = [n for n in slots if n is not None]
    assert len(named) == len(set(named)) == 12 and all(table[n]["tuned"] for n in named)
    assert {n for n, p in table.items() if p.get("tuned")} == set(named)  # every tuned parameter has one slot
    for n, v in zip(slots, g0):
        if n is None:
            assert v == ardusub.INERT
        else:
            lo, hi = table[n]["range"]
            assert v == table[n]["default"] and lo <= v <= hi
    # ArduSub's own defaults (AC_AttitudeControl_Sub.h, AC_PosControl.cpp's Sub block)
    assert dict(zip(slots, g0))["ATC_RAT_RLL_P"] == 0.135 and dict(zip(slots, g0))["PSC_POSZ_P"] == 3.0


def _reference():
    rows = {}
    with REF.open() as f:
        for r in csv.DictReader(line for line in f if not line.startswith("#")):
            rows.setdefault(r["case"], []).append(r)
    return rows


def test_ac_pid_replica_matches_compiled_ardupilot():
    """The replica (double precision, CasADi) against ArduPilot's AC_PID compiled with float32, step by step on
    the same inputs: the largest difference is float32's rounding (docs/ardusub.md)."""
    ref = _reference()
    assert set(ref) == set(CASES)
    dt = 0.0025
    worst = 0.0
    for case, (P, I, D, FF, IMAX, FLTT, FLTE, FLTD) in CASES.items():
        g = {"P": P, "I": I, "D": D, "FF": FF, "IMAX": IMAX, "FLTT": FLTT, "FLTE": FLTE, "FLTD": FLTD}
        st = [ca.SX.sym(n) for n in "TEDI"]
        tg, ms, lim, rs = ca.SX.sym("t"), ca.SX.sym("m"), ca.SX.sym("l"), ca.SX.sym("r")
        out, ff, nxt = ardusub.ac_pid(tuple(st), tg, ms, dt, g, lim, rs)
        f = ca.Function("pid", [*st, tg, ms, lim, rs], [out, ff, *nxt])
        state = [0.0] * 4
        rows = ref[case]
        got = []
        for k, r in enumerate(rows):
            res = [float(v) for v in f(*state, float(r["target"]), float(r["measurement"]), int(r["limit"]), k == 0)]
            state = res[2:]
            got.append([res[0], res[1], state[3], state[0], state[1], state[2]])
        got = np.array(got)
        want = np.array([[float(r[c]) for c in ("output", "ff", "integrator", "target_f", "error_f", "derivative_f")]
                         for r in rows])
        scale = np.maximum(np.abs(want).max(axis=0), 1e-12)
        rel = (np.abs(got - want) / scale).max()
        worst = max(worst, rel)
        assert rel < 2e-5, (case, rel)
        # the limit flag froze the integrator where it would grow: the table and the replica agree there too
        lims = np.array([int(r["limit"]) for r in rows]) == 1
        assert lims.any() and np.allclose(got[lims, 2], want[lims, 2], rtol=1e-5, atol=1e-6 * scale[2])
    assert worst > 0  # float32 against double: not bit-identical (a table that matched itself would be suspect)


def test_mixer_normalises_and_clips():
    m = np.array(ca.evalf(ardusub.mixer(0.0, 0.0, 0.0, 0.5))).ravel()
    assert np.allclose(m[:4], 0) and np.allclose(m[4:], -0.5)  # throttle up: verticals negative (push up)
    m = np.array(ca.evalf(ardusub.mixer(0.8, 0.8, 0.0, 0.8))).ravel()  # roll + pitch + throttle = 2.4 on M6
    assert np.isclose(np.abs(m[4:]).max(), 1.0) and np.isclose(m[5], -1.0)  # the group normalised by its largest
    m = np.array(ca.evalf(ardusub.mixer(0.0, 0.0, 0.3, 0.0))).ravel()
    assert np.allclose(m[:4], [0.3, -0.3, -0.3, 0.3]) and np.allclose(m[4:], 0)


@pytest.mark.parametrize("system, sign", [
    ("bluerov2_heavy_alpha5", -1.0),
    (str(Path(__file__).resolve().parents[1] / "studies/systems/hinsdale_bluerov2_alpha5_identified_t200.toml"), 1.0),
], ids=["heavy", "hinsdale"])
def test_motor_mapping_on_the_bluerov2_heavy(system, sign):
    """Every thruster of a BlueROV2 Heavy frame (the shipped one; the identified Hinsdale vehicle's stand-in
    thrusters) is one ArduSub motor in its place, in ArduSub's order, all mirrored (von Benzon's directions) or
    none (the Robotic Decision Making Lab's), and a positive roll, pitch or yaw or a downward throttle from the
    mixer gives a wrench of that sign, in that DOF only, through the system's thrusters."""
    blue = arvcas.load_system(system)
    P = view(blue.params.vector(), blue.params.layout)
    sel = ardusub.motor_of_thruster(P)
    W = np.array([np.array(ca.evalf(w)).ravel() for w, _ in sel])
    assert np.allclose(W.sum(axis=1), 1) and np.allclose(W.sum(axis=0), 1)  # a permutation
    assert list(W.argmax(axis=1)) == list(range(8))  # the system file lists them in ArduSub's order
    signs = np.array([float(ca.evalf(s)) for _, s in sel])
    assert np.all(signs == sign), signs
    B = np.array(ca.evalf(arvcas.model.thrusters.B_T(P)))
    for k, inputs in ((3, (0.2, 0, 0, 0)), (4, (0, 0.2, 0, 0)), (5, (0, 0, 0.2, 0)), (2, (0, 0, 0, -0.2))):
        out = np.array(ca.evalf(ardusub.mixer(*inputs))).ravel()
        thrust_dir = signs * (W @ out)  # along each thruster's direction (before the map's nonlinearity)
        wrench = B @ thrust_dir
        assert wrench[k] > 0, (k, wrench)  # roll, pitch, yaw right; throttle -0.2 (down): +z
        assert np.abs(np.delete(wrench, k)).max() < 1e-9 * wrench[k], (k, wrench)


def test_param_export_parses_and_names_exist(tmp_path):
    g0 = gains_mod.default_gains("ardusub")
    p = ap.write_param_file(tmp_path / "x.param", g0, system="bluerov2_heavy_alpha5", front="F", member="knee",
                            objectives="f_chat 1, f_rmse 2", date="2026-01-01")
    text = p.read_text()
    for key in ("system: bluerov2_heavy_alpha5", "front: F", "member: knee", "objectives: f_chat 1", "date: 2026"):
        assert key in text
    vals = ap.read_param_file(p)
    table = ardusub.params()["param"]
    assert set(vals) == {n for n in ardusub.slot_names() if n} and set(vals) <= set(table)
    for n, v in vals.items():
        assert v == pytest.approx(table[n]["default"], rel=1e-7)
    # refused, not clipped: a value outside ArduSub's range
    bad = g0.copy()
    bad[ardusub.slot_names().index("ATC_RAT_RLL_P")] = 0.5  # range 0..0.30
    with pytest.raises(ap.ParamFileError, match=r"ATC_RAT_RLL_P = 0.5 is outside ArduSub's range \[0, 0.3\]"):
        ap.write_param_file(tmp_path / "y.param", bad, system="s", front="F", member="0", objectives="")
    assert not (tmp_path / "y.param").exists()
    # a file arvcas did not write is never replaced
    (tmp_path / "z.param").write_text("MY_PARAM 1\n")
    with pytest.raises(ap.ParamFileError, match="not written by arvcas"):
        ap.write_param_file(tmp_path / "z.param", g0, system="s", front="F", member="0", objectives="", force=True)
    with pytest.raises(ap.ParamFileError, match="not 'NAME value'"):
        (tmp_path / "w.param").write_text("ATC_RAT_RLL_P\n")
        ap.read_param_file(tmp_path / "w.param")


def test_cli_writes_the_param_file(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["export-controller", str(out), "--controller", "ardusub", "--system", "bluerov2_heavy_alpha5",
                 "--format", "ardusub-params"]) == 0
    f = out / "bluerov2_heavy_alpha5_ardusub.param"
    assert f.exists() and "ATC_ANG_RLL_P" in ap.read_param_file(f)
    assert main(["export-controller", str(tmp_path / "o2"), "--controller", "pid", "--system", "bluerov2_heavy_alpha5",
                 "--format", "ardusub-params"]) != 0
    assert "not ardusub" in capsys.readouterr().err


@pytest.mark.slow
def test_closed_loop_holds_depth_and_attitude():
    """60 s on the BlueROV2 Heavy (T200 dynamics) without current, waves or arm motion, from the scenario's
    offsets: ALT_HOLD brings depth, roll and pitch to the set point and holds them (the accelerometer loop's
    integrator trims the vehicle's net buoyancy); yaw stays within the T200 dead band's limit cycle; x, y are
    not held (no position sensor in ALT_HOLD)."""
    from arvcas.sim import scenario
    from arvcas.sim.run import Run

    blue = arvcas.load_system("bluerov2_heavy_alpha5")
    cfg = scenario.load_scenario(blue.params.default("scenario"))
    cfg = dataclasses.replace(cfg, time_duration=60.0, current_velocity=(0.0, 0.0, 0.0),
                              disturbance_amplitude=(0.0,) * 6, arm_waypoint=cfg.arm_waypoint[:1], payload_event=(),
                              limits_e_position=100.0)
    r = Run("ardusub", scenario=cfg, system=blue).compile().simulate(seed=0)
    assert r.ok
    late = r.eta[int(30 / cfg.time_h):]
    assert np.abs(late[:, 2]).max() < 0.01 and abs(late[:, 2].mean()) < 0.003  # depth: within 1 cm, no offset
    assert np.abs(late[:, 3:5]).max() < 0.02 and np.abs(late[:, 3:5].mean(axis=0)).max() < 0.005  # roll, pitch
    assert np.abs(late[:, 5]).max() < 0.1  # heading within 6 deg (the T200 dead band's limit cycle)
    assert ((r.pwm >= 1100) & (r.pwm <= 1900)).all()
    after5 = r.eta[int(5 / cfg.time_h):]
    print(f"ardusub closed loop: from 5 s max |z| {np.abs(after5[:, 2]).max():.4g} m, max |roll|, |pitch| "
          f"{np.abs(after5[:, 3:5]).max(axis=0)} rad; from 30 s mean z, roll, pitch {late[:, 2:5].mean(axis=0)}, yaw in [{after5[:, 5].min():.4g}, {after5[:, 5].max():.4g}] rad; "
          f"RMSE {r.rmse}; CHAT {r.chat}")


def test_thrust_of_pwm_is_the_systems_map():
    """The law's thrust of a PWM (the truncated-power form of the map's monotone cubic) is the loop's own map
    (arvcas.model.thrusters.map_thrust) to round-off, over the whole PWM range and beyond."""
    from arvcas.model import thrusters

    blue = arvcas.load_system("bluerov2_heavy_alpha5")
    lay = blue.params.layout
    p = ca.SX.sym("p", len(lay))
    m = thrusters.thruster_maps(view(p, lay))[0]
    x = ca.SX.sym("x")
    F = ca.Function("F", [x, p], [thrusters.pchip_powers(*thrusters.map_table(view(p, lay), m))(x)])
    Pn = view(blue.params.vector(), lay)
    mn = thrusters.thruster_maps(Pn)[0]
    s = np.array([float(ca.evalf(thrusters.state_of(Pn, mn, c))) for c in np.linspace(1050, 1950, 451)])
    got = np.array(F.map(s.size)(s[None, :], ca.repmat(ca.DM(blue.params.vector()), 1, s.size))).ravel()
    want = np.array(thrusters.map_thrust(Pn, mn, ca.DM(s))).ravel()
    assert np.abs(want).max() > 40 and np.abs(got - want).max() < 1e-7


def test_cli_front_member_knee_and_out_of_range_member(tmp_path, capsys):
    """--front F --member knee: the knee's gains with the front, member and objectives in the header; a member with
    a gain beyond ArduSub's range (1.1 x the defaults: PSC_POSZ_P 3.3 > 3) is refused, no file written."""
    from trust_helpers import synthetic_front

    front = synthetic_front(tmp_path / "front.h5", controller="ardusub")
    out = tmp_path / "out"
    assert main(["export-controller", str(out), "--front", str(front), "--member", "knee",
                 "--format", "ardusub-params"]) == 0
    f = next(out.glob("*.param"))
    text = f.read_text()
    assert f"# front: {front}" in text and "# member: knee" in text and "member 1 of the 3 of the front" in text
    vals = ap.read_param_file(f)
    assert vals["ATC_RAT_RLL_P"] == pytest.approx(0.135) and len(vals) == 12
    capsys.readouterr()
    out2 = tmp_path / "out2"
    assert main(["export-controller", str(out2), "--front", str(front), "--member", "2",
                 "--format", "ardusub-params"]) != 0
    assert "PSC_POSZ_P = 3.3 is outside ArduSub's range [1, 3]" in capsys.readouterr().err
    assert not out2.exists()  # refused before anything is written
