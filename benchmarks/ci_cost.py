"""What the test suite costs, file by file and as CI runs it, with a cold compile cache: results/ci/.

Each test file runs in its own ``pytest -p no:xdist`` process with an empty ``ARVCAS_CACHE`` (and its own
``--basetemp``, so the private caches of the ``cache`` fixture survive the run). This module is also the pytest
plugin (``-p benchmarks.ci_cost``) that records, per test phase (set-up, call, tear-down) and per fixture set-up,
the wall time, the CPU time of the process and of its children (the C compiler) and the compiles it started
(:func:`arvcas.build.codegen.stats`). Afterwards every manifest the file's caches hold is read: a function whose
generated C (``c_sha256``) was compiled in more than one file, or under more than one name, is listed under
``repeated_builds``; one compiled under more than one key (as one cache shared by the files would hold it) under
``several_keys``, with the key fields that differ where the manifests record the descriptions; ``one_cache``: the
builds and compile seconds of such a shared cache. ``c_sha256`` leaves out C appended to a function's own (a batch
loop): two keys of one ``c_sha256`` at one flag list are a library with the loop and one without.
CPU time, unlike wall time, changes less when other processes share the machine.

    python benchmarks/ci_cost.py                       # every tests/test_*.py (about an hour of CPU)
    python benchmarks/ci_cost.py tests/test_lockstep.py tests/test_systems.py   # some files, merged into the JSON
    python benchmarks/ci_cost.py --suite 2             # the whole suite as CI runs it: results/ci/suite.json
    python benchmarks/ci_cost.py --report              # the table from results/ci/files.json, costliest first
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results" / "ci" / "files.json"
SUITE = ROOT / "results" / "ci" / "suite.json"
_ENV_OUT = "ARVCAS_CI_COST_OUT"  # where the plugin writes its records (set by the runner)


# ---------------------------------------------------------------------------------------------
# the pytest plugin (active only when the runner set _ENV_OUT)


def _cpu() -> tuple[float, float]:
    """(CPU seconds of this process, CPU seconds of its waited-for children)."""
    me = resource.getrusage(resource.RUSAGE_SELF)
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime, ch.ru_utime + ch.ru_stime


def _compiles() -> int:
    from arvcas.build import codegen

    return codegen.stats()["compile"] + codegen.stats()["private"]


class _Meter:
    def __init__(self):
        self.wall, (self.cpu, self.child), self.n = time.perf_counter(), _cpu(), _compiles()

    def done(self) -> dict:
        cpu, child = _cpu()
        return {"wall_s": round(time.perf_counter() - self.wall, 3), "cpu_s": round(cpu - self.cpu, 3),
                "cc_cpu_s": round(child - self.child, 3), "compiles": _compiles() - self.n}


_TESTS: list[dict] = []
_FIXTURES: list[dict] = []
_FAILED: list[dict] = []  # which tests failed, in which phase, and the last line of why


def _phase(item, phase: str):
    m, t0 = _Meter(), time.time()
    yield
    rec = next((t for t in reversed(_TESTS) if t["test"] == item.nodeid), None)
    if rec is None:
        rec = {"test": item.nodeid, "start": round(t0, 3)}
        _TESTS.append(rec)
    rec[phase] = m.done()
    rec["end"] = round(time.time(), 3)


def _hookwrapper(f):
    import pytest

    return pytest.hookimpl(hookwrapper=True)(f)


if os.environ.get(_ENV_OUT):
    @_hookwrapper
    def pytest_runtest_setup(item):
        yield from _phase(item, "setup")

    @_hookwrapper
    def pytest_runtest_call(item):
        yield from _phase(item, "call")

    @_hookwrapper
    def pytest_runtest_teardown(item):
        yield from _phase(item, "teardown")

    @_hookwrapper
    def pytest_fixture_setup(fixturedef, request):
        m = _Meter()
        yield
        rec = m.done()
        if rec["wall_s"] >= 0.05:
            param = getattr(request, "param", None)
            _FIXTURES.append({"fixture": fixturedef.argname, "scope": fixturedef.scope,
                              "param": None if param is None else str(param),
                              "first_test": request.node.nodeid, **rec})

    def pytest_runtest_logreport(report):
        if report.failed:
            crash = getattr(report.longrepr, "reprcrash", None)  # the assertion's or exception's own message
            lines = str(report.longrepr).strip().splitlines()
            why = crash.message if crash is not None else (lines[-1] if lines else "")
            _FAILED.append({"test": report.nodeid, "when": report.when, "why": " ".join(why.split())[:300]})

    def pytest_sessionfinish(session, exitstatus):
        worker = os.environ.get("PYTEST_XDIST_WORKER")  # under xdist: one file per worker (and the controller's)
        cpu, child = _cpu()
        Path(os.environ[_ENV_OUT] + (f".{worker}" if worker else "")).write_text(json.dumps(
            {"worker": worker, "tests": _TESTS, "fixtures": _FIXTURES, "failed": _FAILED, "exitstatus": int(exitstatus),
             "cpu_s": round(cpu + child, 1)}))


# ---------------------------------------------------------------------------------------------
# the runner


def _manifests(d: Path) -> list[dict]:
    out = []
    for p in d.rglob("*.json"):
        try:
            m = json.loads(p.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(m, dict) and "c_sha256" in m and "compile_time_s" in m:
            out.append({k: m.get(k) for k in ("name", "c_sha256", "key", "compile_time_s", "codegen_time_s",
                                              "n_instructions", "description", "flags")} | {"opt": next(
                                              (f for f in m["flags"] if f.startswith("-O")), None)})
    return out


def _pytest(args: list[str], python: str) -> dict:
    """pytest with ``args`` in a new process with an empty cache: its timings, CPU and the builds it made."""
    with tempfile.TemporaryDirectory(prefix="arvcas-ci-cost-") as tmp:
        tmp = Path(tmp)
        cache, base, out = tmp / "cache", tmp / "base", tmp / "out.json"
        cache.mkdir(mode=0o700)
        env = os.environ | {"ARVCAS_CACHE": str(cache), _ENV_OUT: str(out),
                            "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        p = subprocess.run([python, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "benchmarks.ci_cost",
                            f"--basetemp={base}", *args], cwd=ROOT, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        recs = [json.loads(f.read_text()) for f in sorted(tmp.glob("out.json*"))]
        tail = p.stdout.strip().splitlines()[-1:] if p.stdout.strip() else []
        return {"wall_s": round(wall, 1),
                "cpu_s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 1),
                "pytest_rc": p.returncode, "summary": tail[0] if tail else "",
                "workers": {r["worker"] or "main": {"cpu_s": r["cpu_s"], "n_tests": len(r["tests"])} for r in recs},
                "tests": [t | {"worker": r["worker"]} for r in recs for t in r["tests"]],
                "fixtures": [x for r in recs for x in r["fixtures"]],
                "failed": [x for r in recs for x in r.get("failed", [])],
                "builds": _manifests(cache) + _manifests(base)}


def run_file(test_file: str, python: str) -> dict:
    """One test file alone (no xdist) with an empty cache."""
    return {"file": test_file, **_pytest(["-p", "no:xdist", test_file], python)}


def run_suite(n: int, python: str, files: list[str] = ()) -> dict:
    """The whole suite as CI runs it (``-n n --dist loadscope --no-loadscope-reorder``, .ci/run) with an empty
    cache: per worker, its CPU and how long it sat idle at the end (the balance); per file, its tests' CPU.
    Interrupted (SIGINT to pytest), the workers still write what they ran: the summary says ``complete: false``."""
    r = _pytest(["-n", str(n), "--dist", "loadscope", "--no-loadscope-reorder", "-rs", *files], python)
    t_end = max(t["end"] for t in r["tests"])
    for w, rec in r["workers"].items():
        mine = [t for t in r["tests"] if (t["worker"] or "main") == w]
        if mine:
            rec["idle_at_end_s"] = round(t_end - max(t["end"] for t in mine), 1)
    return r


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True).stdout.strip()


def _test_cpu(t: dict) -> float:
    return sum(t[k]["cpu_s"] + t[k]["cc_cpu_s"] for k in ("setup", "call", "teardown") if k in t)


def _test_row(t: dict) -> dict:
    ph = {k: t[k] for k in ("setup", "call", "teardown") if k in t}
    return {"test": t["test"], "cpu_s": round(_test_cpu(t), 2),
            **{f"{k}_cpu_s": round(v["cpu_s"] + v["cc_cpu_s"], 2) for k, v in ph.items()},
            "wall_s": round(sum(v["wall_s"] for v in ph.values()), 2), "compiles": sum(v["compiles"] for v in ph.values())}


def _repeated(builds: list[tuple[str, dict]]) -> list[dict]:
    """Functions whose generated C at one level was compiled more than once (in several files' caches, or
    under several keys of one cache): the costliest first."""
    by_c: dict[str, list] = defaultdict(list)
    for f, b in builds:
        by_c[b["c_sha256"] + str(b["opt"])].append((f, b))
    out = [{"names": sorted({b["name"] for _, b in bs}), "opt": bs[0][1]["opt"], "n_builds": len(bs),
            "files": sorted({f for f, _ in bs if f}),
            "compile_s_total": round(sum(b["compile_time_s"] for _, b in bs), 1)}
           for bs in by_c.values() if len(bs) > 1]
    return sorted(out, key=lambda r: -r["compile_s_total"])


def _fields(description: str) -> dict[str, str]:
    """``name=value`` fields of a compile description (a dataclass repr and ``key=value`` words)."""
    parts = re.split(r",\s(?=\w+=)|\s(?=\w+=)|\((?=\w+=)", description)
    return dict(p.split("=", 1) for p in parts if re.match(r"\w+=", p))


def _several_keys(builds: list[tuple[str, dict]]) -> list[dict]:
    """Functions whose generated C at one level was compiled under more than one cache key (as one cache shared
    by the files would hold them): the key fields that differ, when the manifests record the descriptions."""
    by_c: dict[str, list] = defaultdict(list)
    for f, b in builds:  # the whole flag list where the record has it (another ISA is another library)
        by_c[b["c_sha256"] + str(b.get("flags") or b["opt"])].append((f, b))
    out = []
    for bs in by_c.values():
        keys = {b["key"]: b for _, b in bs}
        if len(keys) < 2:
            continue
        descs = [_fields(b["description"]) if b.get("description") else None for b in keys.values()]
        known = [d for d in descs if d is not None]
        differ = sorted({k for d in known for k in d if any(e.get(k) != d.get(k) for e in known)})
        out.append({"name": bs[0][1]["name"], "opt": bs[0][1]["opt"], "n_keys": len(keys),
                    "files": sorted({f for f, _ in bs if f}),
                    "compile_s_total": round(sum(b["compile_time_s"] for b in keys.values()), 1),
                    "undescribed_keys": sum(d is None for d in descs), "fields_that_differ": differ})
    return sorted(out, key=lambda r: -r["compile_s_total"])


def _one_cache(builds: list[dict]) -> dict:
    """What the files' builds would be in one cache that they shared: the distinct keys, their compile seconds."""
    keys = {b["key"]: b for b in builds}
    return {"builds": len(keys), "compile_s": round(sum(b["compile_time_s"] for b in keys.values()), 1)}


def _costliest(tests: list[dict], fixtures: list[dict]) -> dict:
    rows = sorted((_test_row(t) for t in tests), key=lambda r: -r["cpu_s"])
    fx = sorted(({k: v for k, v in x.items() if k != "cc_cpu_s"} | {"cpu_s": round(x["cpu_s"] + x["cc_cpu_s"], 2)}
                 for x in fixtures if x["scope"] != "function" or x["wall_s"] >= 1.0), key=lambda x: -x["cpu_s"])
    return {"tests": rows[:40], "fixtures": fx[:30]}


def summarise_files(files: dict[str, dict]) -> dict:
    """Each file run alone: per file (costliest first), the costliest tests and fixtures, repeated builds."""
    per_file = sorted(({"file": Path(f).name, "cpu_s": r["cpu_s"], "tests_cpu_s": round(sum(map(_test_cpu, r["tests"])), 1),
                        "wall_s": r["wall_s"], "summary": r["summary"], "failed": r.get("failed", []),
                        "builds": len(r["builds"]),
                        "compile_s": round(sum(b["compile_time_s"] for b in r["builds"]), 1)}
                       for f, r in files.items()), key=lambda r: -r["cpu_s"])
    return {"files": per_file, "total_cpu_s": round(sum(r["cpu_s"] for r in per_file), 1),
            **_costliest([t for r in files.values() for t in r["tests"]], [x for r in files.values() for x in r["fixtures"]]),
            "repeated_builds": _repeated([(Path(f).name, b) for f, r in files.items() for b in r["builds"]]),
            "several_keys": _several_keys([(Path(f).name, b) for f, r in files.items() for b in r["builds"]]),
            "one_cache": _one_cache([b for r in files.values() for b in r["builds"]])}


def summarise_suite(r: dict) -> dict:
    """The whole suite under xdist: per worker, per file (the sum of its tests' phases), repeated builds."""
    by_file: dict[str, list] = defaultdict(list)
    for t in r["tests"]:
        by_file[t["test"].split("::")[0]].append(t)
    per_file = sorted(({"file": Path(f).name, "tests_cpu_s": round(sum(map(_test_cpu, ts)), 1),
                        "worker": ts[0]["worker"], "n_tests": len(ts)} for f, ts in by_file.items()),
                      key=lambda x: -x["tests_cpu_s"])
    return {"complete": r["pytest_rc"] in (0, 1), "n_tests": len(r["tests"]),  # 2: interrupted (SIGINT)
            "wall_s": r["wall_s"], "cpu_s": r["cpu_s"], "summary": r["summary"], "failed": r.get("failed", []),
            "workers": r["workers"], "builds": len(r["builds"]), "compile_s": round(sum(b["compile_time_s"] for b in r["builds"]), 1),
            "files": per_file, **_costliest(r["tests"], r["fixtures"]),
            "repeated_builds": _repeated([("", b) for b in r["builds"]]),
            "several_keys": _several_keys([("", b) for b in r["builds"]])}


def _stamp(commit: str | None = None, opt_level: str | None = None) -> dict:
    if commit is None:
        commit = (_git("rev-parse", "HEAD") or "unknown") + (
            "+dirty" if _git("status", "--porcelain", "--untracked-files=no") else "")
    return {"git_commit": commit, "nproc": os.cpu_count(),
            "opt_level": opt_level or os.environ.get("ARVCAS_OPT_LEVEL", "tests/conftest.py's")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", help="test files (default: every tests/test_*.py)")
    ap.add_argument("--python", default=sys.executable)
    ap.add_argument("--suite", type=int, metavar="N", help="run the whole suite once with -n N --dist loadscope")
    ap.add_argument("--raw", type=Path, default=Path(tempfile.gettempdir()) / "arvcas-ci-cost-raw.json",
                    help="the per-file records, merged across calls (default: %(default)s)")
    ap.add_argument("--out", type=Path, help=f"default: {OUT.relative_to(ROOT)} (each file alone), "
                                             f"{SUITE.relative_to(ROOT)} (--suite)")
    ap.add_argument("--from-raw", action="store_true", help="summarise the records in --raw again, run nothing")
    ap.add_argument("--commit", help="with --from-raw: the commit the records were measured on (a tree exported "
                                     "by git archive has no git to ask)")
    ap.add_argument("--opt-level", default=None, help="with --from-raw: the level the tests built at")
    ap.add_argument("--report", action="store_true", help="print the table of results/ci/files.json and exit")
    a = ap.parse_args(argv)
    if a.report:
        doc = json.loads(OUT.read_text())
        for r in doc["files"]:
            print(f"{r['cpu_s']:8.1f} s CPU {r['wall_s']:8.1f} s wall {r['builds']:4d} builds  {r['file']}")
        print(f"{doc['total_cpu_s']:8.1f} s CPU in all")
        return 0
    if a.suite:
        if a.from_raw:
            r = json.loads(a.raw.read_text())
        else:
            r = run_suite(a.suite, a.python, a.files)
            a.raw.write_text(json.dumps(r))
        doc = {"what": f"the whole suite, pytest -n {a.suite} --dist loadscope, an empty compile cache "
                       "(benchmarks/ci_cost.py --suite): wall and CPU seconds (pytest, its workers, their compilers)",
               **_stamp(a.commit, a.opt_level), **summarise_suite(r)}
        out = a.out or SUITE
    else:
        files = a.files or sorted(str(p.relative_to(ROOT)) for p in (ROOT / "tests").glob("test_*.py"))
        for f in files:
            if not (ROOT / f).is_file():
                sys.exit(f"ci_cost: no test file {f}")
        raw = json.loads(a.raw.read_text()) if a.raw.exists() else {}
        for f in [] if a.from_raw else files:
            r = run_file(f, a.python)
            raw[f] = r
            a.raw.write_text(json.dumps(raw))
            print(f"{r['cpu_s']:8.1f} s CPU {r['wall_s']:8.1f} s wall {len(r['builds']):4d} builds  {f}  {r['summary']}",
                  flush=True)
        doc = {"what": "each tests/ file run alone (pytest -p no:xdist) with an empty compile cache: CPU seconds of "
                       "pytest and its compiler processes (benchmarks/ci_cost.py)", **_stamp(a.commit, a.opt_level),
               **summarise_files(raw)}
        out = a.out or OUT
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
