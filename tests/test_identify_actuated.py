"""The actuated synthetic study, short: a BlueROV2 driven by PWM through its T200 map, with a depth drift the
model lacks, identified from the command line (studies/validation/actuated/run.py, results/validation/actuated/).

The references are the truth the trials were simulated with (the shipped ``bluerov2``) and what the logs
must hold by construction: every PWM inside the T200 table's range, the commands read back as written, the
vehicle's depth moved by the unmodelled force.
"""

from __future__ import annotations


import numpy as np
import pytest

import arvcas
from arvcas.ident import logs
from script_helpers import load_script



def _study():
    return load_script("studies/validation/actuated/run.py", "actuated_run")


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    run = _study()
    work = tmp_path_factory.mktemp("actuated")
    truth = arvcas.load_system(run.SYSTEM)
    paths = {d: run.write_trials(work, truth, d, trials=3, duration=DURATION) for d in (False, True)}
    return run, work, truth, paths


DURATION = 12.0


def test_driven_trials(case):
    run, work, truth, paths = case
    lg = logs.load_log(paths[True][0], n_joints=0, thruster_names=truth.structure.thrusters)
    assert set(lg.command) == set(truth.structure.thrusters) and lg.command_unit["T1"] == "us"
    C = np.stack([lg.command[n] for n in truth.structure.thrusters])
    assert 1100 <= C.min() < 1472 and 1528 < C.max() <= 1900  # both senses of the T200 table, inside its range
    assert set(lg.measured()) == {"z", "roll", "pitch", "yaw", "p", "q", "r"}  # the vehicle's own sensors only
    drift = run.depth_drift(work, 3)  # 0 -> 1.5, 2, 2.5 N of heave force over 12 s
    assert all(0.02 < d < 0.5 for d in drift) and drift[0] < drift[1] < drift[2]


FREE = ("hydro.Z_w", "vehicle.volume")


@pytest.fixture(scope="module")
def fits(case):
    run, work, truth, paths = case
    start = run.start_system(work, truth)
    out = {}
    for cost, h in run.COSTS:
        fit = run.identify(start, paths[True], work / "fits" / cost, free=FREE, cost=cost, horizon=h,
                           jackknife=False, max_iter=60)
        assert fit["cost"] == cost and fit["horizon"] == h and list(fit["parameters"]) == list(FREE)  # --json
        out[cost] = run.rows(fit, {n: float(truth.params[n]) for n in FREE})
    return out


def test_drift_costs(fits):
    """With the depth drift the model lacks and only the heave damping and the buoyancy free, the simulation
    error moves the heave damping to explain the drift (measured: 35 % off, its Fisher interval far from the
    truth); the prediction error, whose segments restart from the log every 0.5 s, keeps it near the truth
    (measured: 8 % off). With nine parameters free it does not (results/validation/actuated/README.md): the
    unmeasured surge and sway velocities it restarts from bend the others."""
    sim, pred = fits["simulation"]["hydro.Z_w"], fits["prediction"]["hydro.Z_w"]
    assert abs(pred["error_pct"]) < 15.0
    assert abs(sim["error_pct"]) > 2 * abs(pred["error_pct"]) and abs(sim["error_pct"]) > 20.0
    assert not sim["fisher_covers"]  # the drift makes the Fisher interval claim a precision it does not have
