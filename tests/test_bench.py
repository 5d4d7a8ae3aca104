"""`arvcas bench --quick` runs end to end and writes complete, finite figures.

Only that everything works is checked here, never how fast anything is: speed is measured by the
benchmark (results/bench.md), not asserted in a timed test.
"""

from __future__ import annotations

import json
import math

import pytest

from arvcas.cli import bench_module

bench = bench_module()
from arvcas.cli import main


def _numbers(node, where=""):
    """(path, value) of every number in a JSON tree (bools and strings skipped)."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _numbers(v, f"{where}.{k}" if where else k)
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _numbers(v, f"{where}[{i}]")
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        yield where, node


@pytest.mark.slow
def test_bench_quick_writes_complete_finite_figures(tmp_path, capsys):
    assert main(["bench", "--quick", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "bench.json").read_text())
    assert res["mode"] == "quick"
    for path in bench.REQUIRED_KEYS:
        node = res
        for k in path.split("."):
            assert isinstance(node, dict) and k in node, f"bench.json lacks {path}"
            node = node[k]
    assert set(res["plant"]) == {"vehicle_rhs", "arm_wrench", "uvms_rhs", "allocate", "thrust",
                                 "vehicle_rhs_jac", "uvms_rhs_jac"}
    assert res["compile"]["opt_sweep"]["run"] and res["compile"]["opt_sweep"]["uvms_rhs"]
    for section in ("plant", "closed_loop", "compile"):
        nums = list(_numbers(res[section], section))
        assert nums
        for where, v in nums:
            assert math.isfinite(v) and v > 0, f"{where} = {v}"
    for where, v in _numbers(res["machine"], "machine"):  # load averages and CPU shares may be 0
        assert math.isfinite(v) and v >= 0, f"{where} = {v}"
    md = (tmp_path / "bench.md").read_text()
    for heading in ("## 1. Plant functions", "## 2. Closed loop", "## 3. Compiling", "## 7. The exported controller",
                    "## 8. Lockstep lanes in the runs", "## Recommendation"):
        assert heading in md
    assert "| uvms_rhs |" in md and "| uvms_rhs_jac |" in md and "QUICK MODE" in md
    assert "### Calling the dynamics from other code" in md and "written by hand in NumPy" in md


def _sweep(rows):
    st = lambda x: {"median": x, "min": x, "max": x, "n": 1}  # noqa: E731
    return {"default_opt_level": "-O2",
            "opt_sweep": {"run": [{"opt_level": lv, "cc_s": st(cc), "run_s": st(rs)} for lv, cc, rs in rows]}}


def test_recommendation_rule():
    """Fastest-compiling level among those within RUN_TIME_TOLERANCE of the fastest run."""
    tol = bench.RUN_TIME_TOLERANCE
    r = bench._recommend(_sweep([("-O0", 1.0, 0.30), ("-O1", 7.0, 0.100), ("-O2", 10.0, 0.100 * (1 - tol / 2)),
                                 ("-O3", 11.0, 0.120)]))
    assert r["opt_level"] == "-O1" and not r["keep_default"]
    r = bench._recommend(_sweep([("-O0", 1.0, 0.30), ("-O1", 7.0, 0.12), ("-O2", 10.0, 0.10), ("-O3", 11.0, 0.10)]))
    assert r["opt_level"] == "-O2" and r["keep_default"] and "paid back after" in r["text"]


def test_lockstep_rewrite_is_bitwise_equal_and_refuses_what_it_cannot_rewrite(tmp_path):
    """benchmarks/lockstep.py: every lane of the rewritten plant step equals the scalar call to the bit
    (the script fails otherwise), and a line outside the rewrite's vocabulary stops it by name."""
    import importlib

    lockstep = importlib.import_module("benchmarks.lockstep")
    r = lockstep.measure(tmp_path, evals=400, reps=1)
    assert r["lanes"] and all(v["bitwise_equal"] and v["lane_ns_min"] > 0 for v in r["lanes"].values())
    assert (tmp_path / "README.md").is_file() and json.loads((tmp_path / "lockstep.json").read_text())["lanes"]
    src = "static int casadi_f0(const casadi_real** arg) {\n  casadi_real a0;\n  a0=atan2(a0,a0);\n  return 0;\n}\n"
    with pytest.raises(SystemExit, match="toy: an operation this rewrite does not handle: a0=atan2"):
        lockstep.lane_c(src, "toy", 2)
