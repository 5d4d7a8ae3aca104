"""The whole benchmark: every section in one process, then bench.json and bench.md.

Part of the benchmark package (:mod:`arvcas.bench`, whose docstring says what is measured and how).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

from arvcas.build import codegen
from arvcas.sim import scenario
from arvcas.system.params import load as load_params
from arvcas.bench.closed_loop import _bench_closed_loop
from arvcas.bench.common import Settings, _CpuMeter, _default_opt_level, _machine, _wait_for_load
from arvcas.bench.compiling import _bench_compile, _recommend
from arvcas.bench.cost import _bench_cost, write_files as _write_cost_files
from arvcas.bench.controller import _bench_controller
from arvcas.bench.identification import _bench_identification
from arvcas.bench.lanes import _bench_lanes
from arvcas.bench.plant import _Driver, _bench_plant
from arvcas.bench.report import render_markdown
from arvcas.bench.startup import _bench_startup
from arvcas.bench.systems import _bench_systems
from arvcas.bench.targets import _bench_targets

SECTIONS = ("plant", "closed_loop", "targets", "compile", "startup", "systems", "identification", "controller", "lanes",
            "cost")


def run(out: str | Path | None = "results", quick: bool = False, wait_load: float | None = None,
        wait_max_s: float = 900.0, log: Callable[[str], None] | None = None, only: tuple[str, ...] = ()) -> dict:
    """Measure everything once; write ``bench.json`` and ``bench.md`` to ``out`` (unless None).

    ``quick``: tiny repetition counts, the opt sweep only at -O0 (checks that everything works; its
    figures are not for the record). ``wait_load``: first wait (at most ``wait_max_s``) until the
    1-min load average is at most this. ``only``: measure just these sections (:data:`SECTIONS`) and put
    them into ``out``'s existing ``bench.json`` (the others keep their figures; ``partial`` records the
    date, commit and load of each section measured so, and the wait). Returns the result dictionary.
    """
    log = log or (lambda m: print(f"bench: {m}", file=sys.stderr, flush=True))
    if only:
        return _run_only(out, quick, only, log, lambda: _wait_for_load(wait_load, wait_max_s, log)
                         if wait_load is not None else 0.0)
    s = Settings.quick() if quick else Settings.full()
    waited = _wait_for_load(wait_load, wait_max_s, log) if wait_load is not None else 0.0
    machine = _machine()
    machine["load_avg_start"] = [round(x, 2) for x in os.getloadavg()]
    machine["waited_for_load_s"] = round(waited, 1)
    meter = _CpuMeter()
    t_start = time.perf_counter()
    cfg = scenario.load_scenario()
    P = load_params()
    sections: dict[str, dict] = {}
    work = Path(tempfile.mkdtemp(prefix="arvcas-bench-"))
    try:
        driver = _Driver(work, _default_opt_level())
        machine["driver_flags"] = " ".join(driver.flags)
        machine["codegen_flags"] = " ".join([*codegen.BASE_FLAGS, _default_opt_level(), *codegen.FIXED_FLAGS, *codegen.isa_flags()])
        res: dict = {"schema": 1, "mode": s.mode, "machine": machine, "settings": s.__dict__ | {"opt_levels": list(s.opt_levels)}}
        for key, fn in _section_functions(s, cfg, P, driver, work, log):
            m = _CpuMeter()
            t0 = time.perf_counter()
            res[key] = fn()
            sections[key] = {"wall_s": time.perf_counter() - t0, "other_cpu_share": m.share(),
                             "load_avg_end": [round(x, 2) for x in os.getloadavg()]}
    finally:
        shutil.rmtree(work, ignore_errors=True)
    res["recommendation"] = _recommend(res["compile"])
    machine["load_avg_end"] = [round(x, 2) for x in os.getloadavg()]
    machine["other_cpu_share"] = meter.share()
    machine["sections"] = sections
    machine["total_wall_s"] = time.perf_counter() - t_start
    if out is not None:
        write(res, out)
    return res


def _section_functions(s, cfg, P, driver, work, log):
    return (
            ("plant", lambda: _bench_plant(s, driver, work, P, log)),
            ("closed_loop", lambda: _bench_closed_loop(s, cfg, P, log)),
            ("targets", lambda: _bench_targets(s, cfg, P, log)),
            ("compile", lambda: _bench_compile(s, cfg, P, driver, work, log)),
            ("startup", lambda: _bench_startup(s, log)),
            ("systems", lambda: _bench_systems(s, log)),
            ("identification", lambda: _bench_identification(s, log)),
            ("controller", lambda: _bench_controller(s, log)),
            ("lanes", lambda: _bench_lanes(s, log)),
            ("cost", lambda: _bench_cost(s, log)),
    )


def _run_only(out, quick: bool, only: tuple[str, ...], log, wait: Callable[[], float] = lambda: 0.0) -> dict:
    """:func:`run` with ``only``: the named sections measured into ``out``'s bench.json (after ``wait()``,
    which returns the seconds it waited for a quiet machine)."""
    bad = [k for k in only if k not in SECTIONS]
    if bad:
        raise ValueError(f"bench: --only {','.join(bad)}: unknown section; allowed: {', '.join(SECTIONS)}")
    if out is None or not (Path(out) / "bench.json").is_file():
        raise ValueError(f"bench: --only needs an existing {Path(out or '.') / 'bench.json'} to put the sections into")
    res = json.loads((Path(out) / "bench.json").read_text(encoding="utf-8"))
    s = Settings.quick() if quick else Settings.full()
    waited = wait()
    cfg, P = scenario.load_scenario(), load_params()
    work = Path(tempfile.mkdtemp(prefix="arvcas-bench-"))
    try:
        fns = dict(_section_functions(s, cfg, P, _Driver(work, _default_opt_level()), work, log))
        for key in only:
            m, la0, t0 = _CpuMeter(), [round(x, 2) for x in os.getloadavg()], time.perf_counter()
            res[key] = fns[key]()
            mach = _machine()
            res.setdefault("partial", {})[key] = {
                "date": mach["date"], "git_commit": mach["git_commit"], "mode": s.mode, "wall_s": time.perf_counter() - t0,
                "load_avg_start": la0, "load_avg_end": [round(x, 2) for x in os.getloadavg()],
                "other_cpu_share": m.share(), "waited_for_load_s": round(waited, 1)}
    finally:
        shutil.rmtree(work, ignore_errors=True)
    write(res, out)
    return res


def write(res: dict, out: str | Path) -> tuple[Path, Path]:
    """Write ``bench.json`` and ``bench.md`` into the directory ``out`` (created if its parent exists),
    atomically and only over files arvcas wrote (:mod:`arvcas.util.files`); with a ``cost`` section, its
    figures and README into ``out/cost/`` (:func:`arvcas.bench.cost.write_files`)."""
    from arvcas.util import files

    d = files.prepare_dir(Path(out), f"bench: --out {out}")
    pj, pm = d / "bench.json", d / "bench.md"
    text_json = json.dumps(res, indent=1, allow_nan=False) + "\n"
    files.write_text(pj, text_json)
    files.write_text(pm, render_markdown(res))
    if res.get("cost"):
        _write_cost_files(res["cost"], d / "cost")
    return pj, pm
