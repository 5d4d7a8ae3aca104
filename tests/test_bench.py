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
from script_helpers import load_script


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
                    "## 8. Lockstep lanes in the runs", "## 9. Cost against work", "## Recommendation"):
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
    lockstep = load_script("benchmarks/lockstep.py")
    r = lockstep.measure(tmp_path, evals=400, reps=1)
    assert r["lanes"] and all(v["bitwise_equal"] and v["lane_ns_min"] > 0 for v in r["lanes"].values())
    assert (tmp_path / "README.md").is_file() and json.loads((tmp_path / "lockstep.json").read_text())["lanes"]
    src = "static int casadi_f0(const casadi_real** arg) {\n  casadi_real a0;\n  a0=atan2(a0,a0);\n  return 0;\n}\n"
    with pytest.raises(SystemExit, match="toy: an operation this rewrite does not handle: a0=atan2"):
        lockstep.lane_c(src, "toy", 2)


def _cost():
    import importlib

    return importlib.import_module("arvcas.bench.cost")


def test_cost_quick_section_is_complete_finite_and_in_sweep_order(tmp_path):
    """`arvcas bench --quick --only cost` into a copy of the committed bench.json: every sweep's rows in
    sweep order, every number finite, every time positive, the lockstep outputs equal to the one at a time,
    more instructions with more joints, the section in bench.md before the recommendation, the figures and
    README in cost/. (Only that it works: speed is never asserted here.)"""
    from pathlib import Path

    cost = _cost()
    committed = json.loads((Path(__file__).resolve().parents[1] / "results" / "bench.json").read_text())
    committed.pop("cost", None)
    bench.write(committed, tmp_path)  # a bench.json arvcas wrote, to put the section into
    assert main(["bench", "--quick", "--only", "cost", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "bench.json").read_text())
    c = res["cost"]
    assert res["partial"]["cost"]["mode"] == "quick" and c["measured"]["mode"] == "quick"
    ln, bt, jt = c["length"], c["batch"], c["joints"]
    assert [r["length_s"] for r in ln["rows"]] == list(cost.LENGTHS["quick"])
    assert [r["n_runs"] for r in bt["rows"]] == list(cost.BATCH_SIZES["quick"])
    assert [r["joints"] for r in jt["rows"]] == list(cost.JOINTS["quick"])
    for r in ln["rows"]:
        assert r["n_samples"] == round(r["length_s"] / ln["h"]) + 1 and r["ok_share"] == 1.0
    assert all(r["bitwise_equal"] and r["ok_share"] == 1.0 and r["rounds"] >= 1 for r in bt["rows"])
    ins = [r["instructions_per_sample"] for r in jt["rows"]]
    assert all(b > a for a, b in zip(ins, ins[1:])), ins
    assert set(ln["fits"]) == set(cost.LENGTH_SERIES) and set(bt["fits"]) == {"scalar", "lanes"}
    assert set(jt["fits"]) == set(cost.JOINT_SERIES)
    for sweep in (ln, bt, jt):
        for f in sweep["fits"].values():
            n = len(sweep["rows"])
            assert len(f["residual"]) == n and (f["n_points"] == 0 or min(3, n) <= f["n_points"] <= n)
            assert f["linear_everywhere"] == (f["n_points"] == n)
    time_keys = ("median", "min", "max")
    for where, v in _numbers(c, "cost"):
        assert math.isfinite(v), f"{where} = {v}"
        last = where.rsplit(".", 1)[-1]
        if ".rows[" in where and (last in time_keys or last.endswith(("_s", "_s_per_run", "_per_sample"))):
            assert v > 0, f"{where} = {v}"
    md = (tmp_path / "bench.md").read_text()
    assert "## 9. Cost against work" in md
    assert md.index("## 9. Cost against work") < md.index("## Recommendation")
    assert md.index("## 8. Lockstep lanes") < md.index("## 9. Cost against work")
    for name in cost.FIGURES:
        assert (tmp_path / "cost" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    readme = (tmp_path / "cost" / "README.md").read_text()
    assert readme.startswith("# Cost against work") and all(f"]({n})" in readme for n in cost.FIGURES)


def test_linear_fit_finds_where_the_line_holds():
    cost = _cost()
    x = [10.0, 30.0, 100.0, 300.0, 1000.0]
    f = cost.linear_fit(x, [0.5 + 0.01 * v for v in x])
    assert f["linear_everywhere"] and (f["from"], f["to"], f["n_points"]) == (10.0, 1000.0, 5)
    assert abs(f["slope"] - 0.01) < 1e-12 and abs(f["intercept"] - 0.5) < 1e-10
    assert abs(f["proportional_from"] - 450.0) < 1e-6  # 0.5 is 10 % of 0.5 + 0.01 x at x = 450
    # proportional up to 300, then twice the line: the line holds over 10-300, the last point 50 % above it
    f = cost.linear_fit(x, [0.01 * v for v in x[:4]] + [20.0])
    assert not f["linear_everywhere"] and (f["from"], f["to"], f["n_points"]) == (10.0, 300.0, 4)
    assert abs(f["slope"] - 0.01) < 1e-12 and abs(f["residual"][4] - 0.5) < 1e-9 and f["max_residual"] < 1e-9
    assert f["all_points"]["max_residual"] > cost.LINEAR_TOL
    f = cost.linear_fit([1.0, 2.0, 3.0, 4.0], [1.0, 10.0, 1.0, 10.0])  # no three consecutive points on a line
    assert f["n_points"] == 0 and not f["linear_everywhere"] and f["slope"] == f["all_points"]["slope"]
    with pytest.raises(bench.BenchError, match=r"cost: a line needs >= 2 finite points with y > 0"):
        cost.linear_fit([1.0, 2.0], [1.0, 0.0])
