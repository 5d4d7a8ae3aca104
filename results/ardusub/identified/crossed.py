"""Each vehicle's tuned gains on the other vehicle: the BlueROV2 Heavy study's knee and better-than-defaults member
(results/ardusub/ardusub/front.h5) run on the identified Hinsdale vehicle's study (studies/ardusub_identified.toml),
and this folder's two on the Heavy's (studies/ardusub.toml, its ardusub task), each vehicle's own knee beside them
as the check that the evaluation is the study's (it reproduces the front's objectives); then the same gains and
ArduSub's defaults on eight other noise seeds (whether each run holds or diverges). Writes crossed.json beside
this script; results/ardusub/identified/render.py reads it. Run from the repository root (a few runs, plus the
compiled runs' builds if they are not in the cache):

    python results/ardusub/identified/crossed.py
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

import arvcas
from arvcas.tuning.engines import make_engine
from arvcas.tuning.front import read_front
from arvcas.tuning.run import eval_task, evaluate_gains
from arvcas.tuning.study import load_study

HERE = Path(__file__).resolve().parent
SEEDS = tuple(range(1, 9))  # other sensor-noise seeds than the studies' one (seed 0)
ROOT = HERE.parents[2]
# vehicle -> (its study, its ardusub front, the member better than the defaults: that of ../page.py's improvement)
VEHICLES = {
    "identified": (ROOT / "studies" / "ardusub_identified.toml", HERE / "front.h5",
                   HERE / "better_than_defaults" / "hinsdale_bluerov2_alpha5_identified_t200_ardusub.param"),
    "heavy": (ROOT / "studies" / "ardusub.toml", HERE.parent / "ardusub" / "front.h5",
              HERE.parent / "better_than_defaults" / "bluerov2_heavy_ardusub.param"),
}


def _member(param: Path) -> int:
    return int(next(ln for ln in param.read_text().splitlines() if ln.startswith("# member: ")).split(": ")[1])


def main() -> None:
    fronts = {v: read_front(f) for v, (_, f, _) in VEHICLES.items()}
    members = {v: {"knee": fronts[v].knee(), "better_than_defaults": _member(p)} for v, (_, _, p) in VEHICLES.items()}
    out = {}
    for vehicle, (study_path, _, _) in VEHICLES.items():
        study = load_study(study_path)
        task = eval_task(study, "ardusub")
        rows = [(src, which, i) for src in VEHICLES for which, i in members[src].items()]
        gains = np.array([fronts[src].gains[i] for src, _, i in rows])
        ev = evaluate_gains(make_engine(study.engine), task, gains)
        out[vehicle] = {f"{src} {which}": {"member": i, "F": ev.F[k].tolist(), "chat": ev.chat[0, k].tolist(),
                                           "rmse": ev.rmse[0, k].tolist(), "ok": bool(ev.ok[0, k]),
                                           "t_fail": float(ev.t_fail[0, k])}
                        for k, (src, which, i) in enumerate(rows)}
        # the same gains, and ArduSub's defaults, on other noise seeds: does a run's fate depend on its noise draw?
        other = dataclasses.replace(task, draws=tuple((s, *task.draws[0][1:]) for s in SEEDS))
        ev_s = evaluate_gains(make_engine(study.engine), other, np.vstack([gains, fronts[vehicle].table2]))
        for k, row in enumerate(list(out[vehicle].values()) + [out[vehicle].setdefault("defaults", {})]):
            row["other_seeds"] = {"seeds": list(SEEDS), "ok": ev_s.ok[:, k].tolist(),
                                  "t_fail": ev_s.t_fail[:, k].tolist()}
        for (src, which, i), row in zip(rows, out[vehicle].values()):
            if not row["ok"]:  # where it diverged: the tracking error (m, rad) at the run's end (held after it)
                r = arvcas.simulate("ardusub", fronts[src].gains[i], seed=int(study.draws[0].noise_seed),
                                    system=study.params, cfg=study.scenario)
                e = np.asarray(r.e)
                row["e_at_fail"] = e[-1].tolist()
                cfg = study.scenario
                limits = np.array([cfg.limits_e_position] * 3 + [cfg.limits_e_attitude] * 3)
                j = int(np.argmax(np.abs(e[-1]) / limits))  # the DOF past its limit
                n = int(round(row["t_fail"] / r.h)) + 1
                row["fail_dof"], row["h"], row["e_fail_dof"] = j, float(r.h), e[:n, j].tolist()
    def finite(v):  # JSON has no NaN: a diverged run's objectives and t_fail of a run that did not fail are null
        if isinstance(v, dict):
            return {k: finite(x) for k, x in v.items()}
        if isinstance(v, list):
            return [finite(x) for x in v]
        return None if isinstance(v, float) and not np.isfinite(v) else v

    out = finite(out)
    (HERE / "crossed.json").write_text(json.dumps(out, indent=1, allow_nan=False) + "\n")


if __name__ == "__main__":
    main()
