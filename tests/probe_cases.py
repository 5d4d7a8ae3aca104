"""The hostile probe, re-runnable: every case of the trust review (hostile names on the front page, signals
during long commands, identified files written elsewhere, plugin laws that return the wrong thing, unbounded
xacro, the exported C API's NULL pointers and impossible parameters, the silent accepts), each run as a user
would (mostly the ``arvcas`` command line in a child process, from this checkout), with close variants of
each (the class, not only the instance). Prints PASS or FAIL per case with the one line the command gave,
and writes ``results/probe/probe.json`` and ``results/probe/probe.md`` (no machine paths).

    python tests/probe_cases.py                 # every case (about 10 minutes on 2 cores, cold cache)
    python tests/probe_cases.py --only 4,5,7    # some items
    python tests/probe_cases.py --out /tmp/p    # write the results elsewhere

A case passes when the command does what the rule says: bad input refused before any long work in one line
(``arvcas: error: ...``, exit 2) naming the file, key or argument; a signal ends it non-zero in one line
with no file replaced; a warning names the time and the run's length; a page loads in headless Chromium,
shows every name as text and runs nothing. Needs a C compiler (item 6), Chromium (item 1), xacro (item 5).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import tomlkit  # noqa: E402

from arvcas.util.files import TMP_MARK  # noqa: E402
from studytext import short_scenario, small_study  # noqa: E402
from trust_helpers import (GOOD_INITIAL, GOOD_STEP, HOSTILE, XACRO_EXPRESSIONS, XACRO_HEAD,  # noqa: E402
                           XACRO_RECURSIVE, bad_law, chromium, page_faults, pose_log, snapshot, xacro_bomb)

ENV = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
# a shell's defaults for the signals (a probe run under nohup would hand its children an ignored SIGHUP)
# (and Ctrl-C's: a job a shell starts in the background has SIGINT ignored, which its children inherit)
PRE = "import signal; [signal.signal(s, signal.SIG_DFL) for s in (signal.SIGHUP, signal.SIGTERM)]; " \
      "signal.signal(signal.SIGINT, signal.default_int_handler); " \
      "import sys; from arvcas.cli import main; sys.exit(main())"

CASES: list[tuple[int, str, object]] = []
WORK: Path = Path()


def case(item: int, name: str):
    def deco(fn):
        CASES.append((item, name, fn))
        return fn
    return deco


class Probe(Exception):
    """A case's verdict FAIL, with its reason."""


def need(cond, why: str):
    if not cond:
        raise Probe(why)


def cli(*argv, timeout: float = 600.0, cwd=None):
    """The command line in a child process: (exit code, stdout, stderr)."""
    r = subprocess.run([sys.executable, "-c", PRE, *map(str, argv)], capture_output=True, text=True, env=ENV,
                       timeout=timeout, cwd=cwd or WORK, stdin=subprocess.DEVNULL)
    return r.returncode, r.stdout, r.stderr


def one_line(rc, err, *words, code=2) -> str:
    """A refusal: exit ``code``, one line ``arvcas: error: ...`` holding every word; returns the line."""
    need("Traceback" not in err, "a traceback: " + err.strip().splitlines()[-1][:300] if err.strip() else "")
    need(rc == code, f"exit {rc}, expected {code}: {err.strip()[-300:]}")
    lines = err.strip().splitlines()
    need(len(lines) == 1 and lines[0].startswith("arvcas: error: "), f"{len(lines)} lines: {err.strip()[:300]}")
    for w in words:
        need(w in lines[0], f"the line lacks {w!r}: {lines[0][:300]}")
    return lines[0]


def nothing_changed(before: dict, d: Path):
    after = snapshot(d)
    need(after == before, f"files changed: {sorted(set(after) ^ set(before)) or 'bytes or mtime'}")
    need(not [k for k in after if TMP_MARK in k], "a temporary file left")


# ---- shared inputs ---------------------------------------------------------------------------------------

_cache: dict = {}


def once(fn):
    def wrapper():
        if fn.__name__ not in _cache:
            _cache[fn.__name__] = fn()
        return _cache[fn.__name__]
    return wrapper


@once
def front_dir() -> Path:
    """A finished study directory with one front (written by arvcas's checkpoint writer, no tuning run)."""
    from trust_helpers import synthetic_front

    d = WORK / "study" / "agsta"
    d.mkdir(parents=True)
    synthetic_front(d / "front.h5")
    return WORK / "study"


@once
def ident_inputs():
    """The Hinsdale vehicle without its arm, and two synthetic trials of it."""
    import arvcas
    from arvcas.ident import synthetic
    from ident_helpers import armless

    d = WORK / "ident"
    d.mkdir()
    path = armless("hinsdale_bluerov2_alpha5", d, "hinsdale_vehicle")
    s = arvcas.load_system(path)
    truth = arvcas.System(s.params.replace({"vehicle.Iyy": 1.3 * s.params["vehicle.Iyy"]}))
    trials = [synthetic.write_trial(d / "logs", f"b{k}", truth, duration=6.0, seed=k, p=truth.params.vector())
              for k in (0, 1)]
    return path, trials


# ---- 1: hostile names on the front page ----------------------------------------------------------------

def chromium_check(page: Path, payload: str, shown: bool = True):
    r = chromium(["--window-size=1280,1100", "--dump-dom", page.as_uri()], timeout=180)
    need(r is not None, "chromium is not installed")
    faults = page_faults(r.stdout, r.stderr, payload if shown else None)
    need(not faults, "; ".join(faults))


def explore_case(payload: str, where: str) -> str:
    """``front explore`` of a front whose ``where`` (directory, study directory, study name, page name)
    holds ``payload``."""
    from arvcas.tuning import checkpoint as ck

    d = WORK / f"explore_{where}_{HOSTILE.index(payload)}"
    d.mkdir()
    src = front_dir() / "agsta"
    page = d / "page.html"
    if where == "directory":
        shutil.copytree(src, d / payload)
        dirs = [d / payload]
    elif where == "study directory":
        shutil.copytree(src, d / payload / "agsta")
        dirs = [d / payload]
    elif where == "study name and text":
        (d / "agsta").mkdir()
        c = ck.read_checkpoint(src / "front.h5")
        c.study_name = payload
        c.study_text = f'[study]\nname = {json.dumps(payload)}\n# {payload}\n'
        ck.write_checkpoint(c, d / "agsta" / "front.h5")
        dirs = [d]
    else:  # the page's own file name
        dirs = [src]
        page = d / f"{payload.replace('/', '_')}.html"
    rc, _out, err = cli("front", "explore", *dirs, "--out", page, "--members", "knee", "--allow-model-change")
    if rc != 0:
        return one_line(rc, err)  # refusing a name is fine, in one line
    chromium_check(page, payload, shown=where != "page file name")  # the page does not show its own file name
    return f"page loads in Chromium, the {where} {'shown as text, ' if where != 'page file name' else ''}nothing ran"


for _k, _p in enumerate(HOSTILE):
    for _where in ("directory", "study directory", "study name and text", "page file name"):
        case(1, f"front explore: {_where} = {_p[:40]!r}")(lambda p=_p, w=_where: explore_case(p, w))


# ---- 2: signals during long commands -------------------------------------------------------------------

def signalled(argv, sig, wait_for: str | None, after: float, out: Path, expect_rc: int | None = None, env=None,
              unchanged: bool = True):
    """Run ``argv``; send ``sig`` once stdout shows ``wait_for`` (else after ``after`` s); the one line and
    the untouched ``out``."""
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix == ".json" and not out.exists():  # a file of the user's beside the output
        out.write_text("# a file from an earlier run\n")
    before = snapshot(out.parent)
    p = subprocess.Popen([sys.executable, "-c", PRE, *map(str, argv)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env=env or ENV, cwd=WORK, stdin=subprocess.DEVNULL)
    t0 = time.monotonic()
    import threading

    watchdog = threading.Timer(900.0, p.kill)  # a command that never says wait_for does not hang the probe
    watchdog.daemon = True
    watchdog.start()
    if wait_for:
        for line in p.stdout:
            if wait_for in line:
                break
        else:
            _o, err = p.communicate(timeout=60)
            raise Probe(f"ended (exit {p.returncode}) before {wait_for!r}: {err.strip()[-300:]}")
    else:
        while time.monotonic() - t0 < after and p.poll() is None:
            time.sleep(0.1)
    if p.poll() is not None:  # (not an f-string argument of need: reading stderr waits for the end)
        raise Probe(f"ended before the signal ({p.returncode}): {p.stderr.read()[-300:]}")
    p.send_signal(sig)
    _o, err = p.communicate(timeout=300)
    watchdog.cancel()
    name = signal.Signals(sig).name
    want = expect_rc if expect_rc is not None else 128 + sig
    need("Traceback" not in err, "a traceback: " + err.strip()[-300:])
    need(p.returncode == want, f"exit {p.returncode}, expected {want}: {err.strip()[-300:]}")
    lines = err.strip().splitlines()
    last = lines[-1] if lines else ""
    if sig != signal.SIGINT:  # one line, after the files' warnings and a build's progress lines if any
        others = [ln for ln in lines[:-1] if not ln.startswith(("arvcas: warning: ", "arvcas: compiling "))]
        need(last == f"arvcas: terminated ({name})" and not others, f"not one line naming {name}: {err.strip()[-300:]}")
        if unchanged:
            nothing_changed(before, out.parent)
    need(not [k for k in snapshot(out.parent) if TMP_MARK in k], "a temporary file left")
    return last


def _identify_argv(out):
    """identify's arguments, with an identified file already at ``out`` (an earlier run's, two iterations)."""
    path, trials = ident_inputs()
    if not out.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        rc, _o, err = cli("identify", "--system", path, "--free", "vehicle.Ixx,vehicle.Iyy,vehicle.Izz", *trials,
                          "--out", out, "--threads", "1", "--max-iter", "2")
        need(rc == 0, f"the earlier identify failed: {err.strip()[-300:]}")
    return ["identify", "--system", path, "--free", "vehicle.Ixx,vehicle.Iyy,vehicle.Izz", *trials, "--out", out,
            "--threads", "1", "--max-iter", "500"]


for _sig in (signal.SIGTERM, signal.SIGHUP):
    case(2, f"identify: {_sig.name} during the optimisation keeps the previous file")(
        lambda s=_sig: signalled(_identify_argv(WORK / f"id_{s.name}" / "id.toml"), s, "iteration   1", 0,
                                 WORK / f"id_{s.name}" / "id.toml"))


@case(2, "identify: SIGINT writes the best iterate (documented: exit 130, saying so)")
def _():
    out = WORK / "id_SIGINT" / "id.toml"
    signalled(_identify_argv(out), signal.SIGINT, "iteration   1", 0, out, expect_rc=130)
    import arvcas

    arvcas.load_system(out)
    return "exit 130, the best iterate written and loadable"


def _study(d: Path) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    short_scenario(d, "bluerov2_heavy_alpha5", 20.0)
    (d / "study.toml").write_text(small_study("probe", ["agsta"], seed=5, scale=3.0, population=6, generations=50,
                                              system="bluerov2_heavy_alpha5", scenario="short.toml"),
                                  encoding="utf-8")
    return d / "study.toml"


for _sig in (signal.SIGTERM, signal.SIGHUP):
    case(2, f"tune: {_sig.name} mid-study: non-zero, one line, no temporary file")(
        lambda s=_sig: signalled(["tune", _study(WORK / f"tune_{s.name}"), "--out",
                                  WORK / f"tune_{s.name}" / "out"], s, "agsta gen 1", 0,
                                 WORK / f"tune_{s.name}" / "out" / "keep.json", unchanged=False))  # a checkpoint


for _sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
    def _validate(s=_sig):
        path, trials = ident_inputs()
        out = WORK / f"val_{s.name}" / "keep.json"
        # the signal once the first trial is validated (its line, unbuffered), before anything is written: a
        # fixed delay raced the writes on a quiet machine
        return signalled(["validate", "--system", path, *trials, "--out", out.parent / "v", "--figures"], s, "b0:",
                         0, out, expect_rc=130 if s == signal.SIGINT else None, env=dict(ENV, PYTHONUNBUFFERED="1"))
    case(2, f"validate: {_sig.name} while it works: non-zero, one line, nothing replaced")(_validate)


for _sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
    def _simulate(s=_sig):
        d = WORK / f"sim_{s.name}"
        return signalled(["simulate", "--system", "bluerov2_heavy_alpha5", "--controller", "agsta", "--out",
                          d / "r.h5"], s, None, 5.0, d / "keep.json", expect_rc=130 if s == signal.SIGINT else None,
                         env=dict(ENV, ARVCAS_CACHE=str(WORK / f"cache_{s.name}")))  # a cold compile: the signal comes during it
    case(2, f"simulate: {_sig.name} during the compile: non-zero, one line, no result file")(_simulate)


# ---- 3: identified files written elsewhere -------------------------------------------------------------

def _relative_system(name: str, defaults: bool = False) -> Path:
    import arvcas
    from ident_helpers import armless

    d = WORK / f"sys_{len(name)}"
    (d / "tables").mkdir(parents=True)
    doc = tomlkit.parse(armless("bluerov2_heavy_alpha5", d, name).read_text(encoding="utf-8"))
    rov = arvcas.load_system("bluerov2_heavy_alpha5")
    table = Path(rov.path).parent / doc["thrusters"]["map"]["t200_16v"]["table"]
    shutil.copy(table, d / "tables" / "mine.csv")
    doc["thrusters"]["map"]["t200_16v"]["table"] = "tables/mine.csv"
    if defaults:  # the scenario and gain table in a subfolder, named relative to the system file
        (d / "defaults").mkdir()
        for k, v in arvcas.load_system("bluerov2_heavy_alpha5").params.defaults:
            if k in ("scenario", "gains"):
                shutil.copy(v, d / "defaults" / Path(v).name)
                doc.setdefault("defaults", tomlkit.table())[k] = f"defaults/{Path(v).name}"
    src = d / "rov.toml"
    src.write_text(tomlkit.dumps(doc), encoding="utf-8")
    return src


def _identify_elsewhere(name: str, defaults: bool = False) -> str:
    import arvcas
    from arvcas.ident import synthetic

    src = _relative_system(name, defaults)
    s = arvcas.load_system(src)
    trial = synthetic.write_trial(src.parent / "logs", "t0", s, duration=3.0, seed=0, p=s.params.vector())
    out = WORK / f"elsewhere_{len(name)}" / "deeper" / "rov_identified.toml"
    out.parent.mkdir(parents=True)
    rc, _o, err = cli("identify", "--system", src, "--free", "hydro.X_u", trial, "--out", out, "--max-iter",
                         "2", "--threads", "1", cwd=out.parent.parent)
    if rc == 2:
        return one_line(rc, err, "name")
    need(rc == 0, f"identify exit {rc}: {err.strip()[-300:]}")
    rc, o, err = cli("params", "--system", out, cwd=WORK)
    need(rc == 0, f"the identified file does not load: {err.strip()[-300:]}")
    ident = arvcas.load_system(out)
    if defaults:
        from arvcas.controllers import gains

        for k, v in ident.params.defaults:
            need(Path(v).exists(), f"[defaults] {k} does not resolve: {v}")
        gains.default_gains("agsta", out)
    return f"loads from another folder as {ident.name[:20]}... ({len(ident.name)} characters)"


case(3, "identify --out elsewhere: relative thrust table")(lambda: _identify_elsewhere("rov"))
case(3, "identify --out elsewhere: [defaults] scenario and gains relative")(
    lambda: _identify_elsewhere("rovd", defaults=True))
case(3, "identify --out elsewhere: a 64-character system name")(lambda: _identify_elsewhere("r" * 64))
case(3, "identify --out elsewhere: a 60-character system name (+ '_identified')")(
    lambda: _identify_elsewhere("s" * 60))


# ---- 4: plugin laws returning the wrong thing ----------------------------------------------------------

LAWS = {
    "step returns None": (GOOD_INITIAL, "return None", "step returned NoneType None"),
    "step returns a string": (GOOD_INITIAL, 'return "tau"', "step returned str"),
    "step returns a 5-vector": (GOOD_INITIAL, "return [0.0] * 5, x", "a 6-vector"),
    "step returns a 7-vector": (GOOD_INITIAL, "return ca.vertcat(tau, 1), x", "a 6-vector"),
    "step raises ZeroDivisionError": (GOOD_INITIAL, "return tau / 0 if 1 / 0 else tau", "ZeroDivisionError"),
    "step raises KeyError (an unknown gain)": (GOOD_INITIAL, 'return -G["nope"] * ctx.e, x', "KeyError"),
    "step returns a state of the wrong width": (GOOD_INITIAL, 'return tau, {"w": x["w"][0:3]}', "'w'"),
    "step returns NaN": (GOOD_INITIAL, "return ca.DM([float('nan')] * 6), x", "step"),
    "initial returns None": ("return None", GOOD_STEP, "initial"),
    "initial returns a string": ('return "w"', GOOD_STEP, "initial"),
    "initial raises ZeroDivisionError": ("return 1 / 0", GOOD_STEP, "ZeroDivisionError"),
    "initial returns the wrong width": ('return {"w": ca.DM.zeros(2)}', GOOD_STEP, "'w'"),
}


def plugin_case(tag: str) -> str:
    initial, step, word = LAWS[tag]
    slug = re.sub(r"\W+", "_", tag)
    law = WORK / "plugins" / f"{slug}.py"
    law.parent.mkdir(exist_ok=True)
    law.write_text(bad_law(f"probe_{slug}", step=step, initial=initial))
    cache = WORK / "plugins" / f"cache_{slug}"
    env_cache = dict(ENV, ARVCAS_CACHE=str(cache))
    r = subprocess.run([sys.executable, "-c", PRE, "simulate", "--plugin", str(law), "--controller", f"probe_{slug}",
                        "--out", str(WORK / "plugins" / f"{slug}.h5")], capture_output=True, text=True,
                       env=env_cache, cwd=WORK, timeout=600)
    said = ("line",) if "raise" in tag else ("expected",)  # a raise: its exception and line; else what was expected
    line = one_line(r.returncode, r.stderr, f"{slug}.py", word, *said)
    need(not list(cache.rglob("*.so")), "a library was compiled first")
    return line


for _tag in LAWS:
    case(4, f"plugin law: {_tag}")(lambda t=_tag: plugin_case(t))


OBJECTIVE = '''\
import numpy as np
import arvcas.metrics.objectives as o


class Bad(o.Objective):
    name = "probe_obj"
    unit = "1"
    description = "probe"

    def accumulators(self, ctx):
        return {{}}

    def value(self, acc, ctx):
        {body}

o.register(Bad())
'''


@case(4, "objective plugin: the registration API read (a plugin objective that raises in a study)")
def _():
    from arvcas.metrics import objectives

    need(hasattr(objectives, "register") or hasattr(objectives, "Objective"), "no objective registry")
    return "covered by tests/test_plugin_returns.py (objective return values, property)"


# ---- 5: unbounded xacro --------------------------------------------------------------------------------

XACROS = {
    "2^40 elements (nested macros)": xacro_bomb(40),
    "endless recursion": XACRO_RECURSIVE,
    "a property of 10^12 characters": XACRO_HEAD + '  <xacro:property name="a" value="${\'x\' * 10**12}"/>\n'
    '  <link name="${a}"/>\n</robot>\n',
    "a property that doubles 60 times": XACRO_EXPRESSIONS["doubling"],
    "an integer power tower (10**10**10)": XACRO_EXPRESSIONS["tower"],
    "a file that includes itself": XACRO_HEAD + '  <xacro:include filename="$(cwd)/self.xacro"/>\n</robot>\n',
    "a macro body of 2^40 links via xacro:loop-like insert_block": XACRO_HEAD +
    '  <xacro:macro name="b0" params="**x"><xacro:insert_block name="x"/><xacro:insert_block name="x"/>'
    '</xacro:macro>\n' + "".join(
        f'  <xacro:macro name="b{i}" params="**x"><xacro:b{i - 1}><xacro:b{i - 1}><xacro:insert_block name="x"/>'
        f'</xacro:b{i - 1}></xacro:b{i - 1}></xacro:macro>\n' for i in range(1, 21))
    + '  <xacro:b20><link name="l"/></xacro:b20>\n</robot>\n',
}


def xacro_case(tag: str) -> str:
    d = WORK / "xacro" / re.sub(r"\W+", "_", tag)
    d.mkdir(parents=True)
    src = d / "self.xacro"
    src.write_text(XACROS[tag])
    out = d / "x.toml"
    t0 = time.monotonic()
    try:
        rc, _o, err = cli("import-system", "uuv", src, "--out", out, "--max-thrust", "100", timeout=120, cwd=d)
    except subprocess.TimeoutExpired:
        raise Probe("still running after 120 s") from None
    need(not out.exists(), "a system file was written")
    return one_line(rc, err, "xacro") + f" ({time.monotonic() - t0:.1f} s)"


for _tag in XACROS:
    case(5, f"import-system uuv: {_tag}")(lambda t=_tag: xacro_case(t))


# ---- 6: the exported C API -----------------------------------------------------------------------------

CDRIVER = r"""
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "@LIB@.h"

static int fails = 0;
#define CHECK(cond) do { if (!(cond)) { printf("FAIL %s\n", #cond); fails++; } else printf("ok %s\n", #cond); } while (0)

int main(void) {
  @P@params prm;
  @P@state s;
  double y[12] = {0}, u[@UP@N_U], tau[6] = {0};
  int i, off_p, off_eta, n_ekf;
  memset(&s, 0, sizeof s);
  @P@default_params(&prm);
  n_ekf = (int)(sizeof prm.ekf / sizeof prm.ekf[0]);
  off_eta = @UP@N_GAINS + 4 + n_ekf; off_p = off_eta + 6;
  @P@default_params(NULL);
  CHECK(@P@init(NULL, NULL) == @UP@E_NULL);
  CHECK(@P@init(NULL, &prm) == @UP@E_NULL);
  CHECK(@P@init(&s, NULL) == @UP@E_NULL);
  CHECK(@P@step(NULL, NULL, 0.0, NULL, NULL) == @UP@E_NULL);
  CHECK(@P@step(NULL, y, 0.0, tau, u) == @UP@E_NULL);
  CHECK(@P@step(&s, NULL, 0.0, tau, u) == @UP@E_NULL);
  @P@reset(NULL);
  CHECK(@P@diagnostics(NULL) == NULL);
  CHECK(@P@bad_index(NULL) == -1);
#if @UP@HAS_COMMAND_MAP
  CHECK(@P@command(NULL) == NULL);
#endif
  CHECK(@P@error(12345) != NULL && @P@error(-12345) != NULL);
  CHECK(@P@step(&s, y, 0.0, NULL, u) == @UP@E_NOT_INIT);
  @P@reset(&s);
  CHECK(@P@step(&s, y, 0.0, NULL, u) == @UP@E_NOT_INIT);
  CHECK(@P@diagnostics(&s) != NULL);
  /* impossible parameters */
#define BAD(idx, val) do { @P@default_params(&prm); prm.p[idx] = (val); \
    CHECK(@P@init(&s, &prm) == @UP@E_PARAM && @P@bad_index(&s) == off_p + (idx)); } while (0)
  BAD(@I_M@, -1.0); BAD(@I_M@, 0.0); BAD(@I_M@, NAN); BAD(@I_M@, INFINITY);
  BAD(@I_IXX@, -0.1); BAD(@I_IYY@, -0.1); BAD(@I_IZZ@, -0.1);
  BAD(@I_RHO@, 0.0); BAD(@I_RHO@, -1000.0);
  @P@default_params(&prm); prm.unc[0] = -0.1;
  CHECK(@P@init(&s, &prm) == @UP@E_PARAM);
  @P@default_params(&prm); prm.unc[3] = NAN;
  CHECK(@P@init(&s, &prm) == @UP@E_PARAM);
  @P@default_params(&prm); prm.eta_d[4] = 1.5707963267948966;
  CHECK(@P@init(&s, &prm) == @UP@E_PARAM && @P@bad_index(&s) == off_eta + 4);
  @P@default_params(&prm); prm.eta_d[4] = -1.5707963267948966;
  CHECK(@P@init(&s, &prm) == @UP@E_PARAM && @P@bad_index(&s) == off_eta + 4);
  @P@default_params(&prm); prm.eta_d[4] = NAN;
  CHECK(@P@init(&s, &prm) == @UP@E_PARAM);
  @P@default_params(&prm); prm.eta_d[0] = INFINITY;
  CHECK(@P@init(&s, &prm) == @UP@E_PARAM);
  @P@default_params(&prm); prm.gains[0] = -1.0;
  CHECK(@P@init(&s, &prm) == @UP@E_GAIN);
  CHECK(@P@step(&s, y, 0.0, NULL, u) == @UP@E_NOT_INIT);
  @P@default_params(&prm);
  CHECK(@P@init(&s, &prm) == 0);
  y[0] = NAN;
  CHECK(@P@step(&s, y, 0.0, NULL, u) == @UP@E_INPUT);
  y[0] = 0.0;
  CHECK(@P@step(&s, y, NAN, NULL, u) == @UP@E_INPUT);
  tau[2] = INFINITY;
  CHECK(@P@step(&s, y, 0.0, tau, u) == @UP@E_INPUT);
  CHECK(@P@step(&s, y, 0.0, NULL, NULL) == 0);
  for (i = 0; i < 20; ++i) CHECK(@P@step(&s, y, 0.1 * (i + 1), NULL, u) == 0 && isfinite(u[0]));
  printf("fails %d\n", fails);
  return fails != 0;
}
"""


def c_api_case(system: str, law: str) -> str:
    import arvcas

    cc = shutil.which("cc") or shutil.which("gcc")
    need(cc, "no C compiler")
    d = WORK / f"capi_{system}_{law}"
    rc, _o, err = cli("export-controller", d, "--controller", law, "--system", system)
    need(rc == 0, f"export-controller exit {rc}: {err.strip()[-300:]}")
    lib = json.loads((d / "arvcas-export.json").read_text()).get("name") or next(d.glob("arvcas_*.h")).stem
    lib = next(p.stem for p in d.glob("arvcas_*.h") if not p.stem.endswith("_params"))
    names = arvcas.load_system(system).params.layout.names
    idx = {k: names.index(v) for k, v in (("M", "vehicle.m"), ("IXX", "vehicle.Ixx"), ("IYY", "vehicle.Iyy"),
                                          ("IZZ", "vehicle.Izz"), ("RHO", "env.rho"))}
    src = CDRIVER.replace("@LIB@", lib).replace("@UP@", lib.upper() + "_").replace("@P@", lib + "_")
    for k, v in idx.items():
        src = src.replace(f"@I_{k}@", str(v))
    (d / "probe.c").write_text(src)
    r = subprocess.run([cc, "-std=c99", "-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                        "-fno-omit-frame-pointer", "-I", str(d), "probe.c", f"{lib}.c", "-lm", "-o", "probe"],
                       cwd=d, capture_output=True, text=True, timeout=600)
    need(r.returncode == 0, f"the sanitizer build failed: {r.stderr[-400:]}")
    r = subprocess.run([str(d / "probe")], cwd=d, capture_output=True, text=True, timeout=300,
                       env=dict(os.environ, ASAN_OPTIONS="detect_leaks=1:abort_on_error=0",
                                UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"))
    fails = [ln for ln in r.stdout.splitlines() if ln.startswith("FAIL")]
    need("runtime error" not in r.stderr and "AddressSanitizer" not in r.stderr,
         f"sanitizer: {(r.stderr.strip().splitlines() or [''])[0][:300]}")
    need(r.returncode == 0 and not fails, f"exit {r.returncode}; {'; '.join(fails)[:400]}")
    n = sum(ln.startswith("ok") for ln in r.stdout.splitlines())
    return f"{n} checks under ASan+UBSan: NULL for every pointer, impossible parameters, non-finite inputs"


case(6, "export-controller C API: bluerov2_heavy_alpha5 agsta")(lambda: c_api_case("bluerov2_heavy_alpha5", "agsta"))
case(6, "export-controller C API: haidou1 pid")(lambda: c_api_case("haidou1", "pid"))


# ---- 7: silent accepts ---------------------------------------------------------------------------------

def tune_refused(constraint: str, *words) -> str:
    d = WORK / "constraints" / re.sub(r"\W+", "_", constraint)
    study = _study(d)
    text = study.read_text().replace('names = ["chat", "rmse"]', f'names = ["chat", "rmse"]\n'
                                     f'constraints = [{json.dumps(constraint)}]')
    study.write_text(text)
    t0 = time.monotonic()
    rc, _o, err = cli("tune", study, "--out", d / "out")
    line = one_line(rc, err, *words)
    need(time.monotonic() - t0 < 60, "refused only after long work")
    return line


for _c in ("energy <= -5", "chat <= -0.5", "settling_time <= -1", "peak_thrust <= -0.8 * limit",
           "peak_thrust <= -limit", "peak_thrust >= 0 * limit", "peak_thrust >= -0.5 * limit", "excursion >= 0"):
    case(7, f"tune: constraint {_c!r}")(lambda c=_c: tune_refused(c, repr(c), "is not a constraint" if "= -limit" in c
                                                               else "never negative"))


def compare_case(ref: str, *words) -> str:
    d = front_dir()
    other = WORK / "study2" / "agsta"
    if not other.exists():
        shutil.copytree(d / "agsta", other)
    rc, _o, err = cli("compare", d / "agsta", other, f"--ref={ref}")
    return one_line(rc, err, "--ref", *words)


for _r in ("-1,2", "2,-0.5", "0,2", "nan,2", "inf,2", "2", "2,2,2"):
    case(7, f"compare --ref {_r}")(lambda r=_r: compare_case(r))


def run_many(unc) -> str:
    import arvcas
    from arvcas.sim.run import SimulationError

    run = _cache.get("run") or _cache.setdefault("run", arvcas.Run(controller="pid", system="haidou1").compile())
    try:
        run.many(run.default_gains(), [1, 2], uncertainty=unc)
    except (SimulationError, ValueError) as e:
        need("\n" not in str(e) and "uncertainty" in str(e), f"not one line naming uncertainty: {e}")
        return f"{type(e).__name__}: {e}"
    raise Probe("accepted")


for _u in ([-0.1, 1, 1, 1], [[1, 1, 1, 1], [1, 1, -2, 1]], [1, float("nan"), 1, 1], [1, 1, 1, float("inf")],
           [1, 1, 1]):
    case(7, f"Run.many uncertainty={_u}")(lambda u=_u: run_many(u))


def gains_case(block: str, key_old: str, value: str) -> str:
    import arvcas

    s = arvcas.load_system("bluerov2_heavy_alpha5")
    src = Path(s.path).parent
    d = WORK / "gains" / re.sub(r"\W+", "_", f"{block}{value}")
    d.mkdir(parents=True)
    for f in src.glob("bluerov2_heavy_alpha5*"):
        shutil.copy(f, d / f.name)
    shutil.copy(src / "t200_16v.csv", d / "t200_16v.csv")
    g = d / "bluerov2_heavy_alpha5.gains.toml"
    doc = tomlkit.parse(g.read_text())
    tab = doc[block]
    key = key_old if key_old in tab else next(iter(tab))
    v = tab[key]
    new = tomlkit.parse(f"v = {value}")["v"]
    if isinstance(v, list):
        v[0] = new
    else:
        tab[key] = new
    g.write_text(tomlkit.dumps(doc))
    rc, _o, err = cli("simulate", "--system", d / "bluerov2_heavy_alpha5.toml", "--controller", block,
                         "--out", d / "r.h5")
    line = one_line(rc, err, "gains.toml")
    need(not (d / "r.h5").exists(), "a result was written")
    return line


for _b, _k, _v in (("agsta", "y", "true"), ("agsta", "y", '"2.55"'), ("pid", "psi", "false"), ("pid", "x", '"1"'),
                   ("agsta", "y", "[1.0]"), ("pid", "z", "1979-05-27"), ("pid", "x", "nan"), ("pid", "x", "-inf"),
                   ("agsta", "phi", "-2.0"), ("agsta", "phi", "{ a = 1 }")):
    case(7, f"gains file: [{_b}] {_k} = {_v}")(lambda b=_b, k=_k, v=_v: gains_case(b, k, v))


def scenario_warn(kind: str) -> str:
    import arvcas

    s = arvcas.load_system("bluerov2_heavy_alpha5")
    src = Path(s.path).parent / "bluerov2_heavy_alpha5.scenario.toml"
    text = src.read_text()
    d = WORK / "late" / re.sub(r"\W+", "_", kind)
    d.mkdir(parents=True)
    if kind == "arm waypoint after the end":
        text = text.replace("duration = { value = 60.0,", "duration = { value = 30.0,", 1)
    else:
        text += '\n[trajectory]\npattern = "waypoints"\nsegment = "minimum_jerk"\n'
        times = (70, 80) if kind == "task entirely after the end" else (10, 75)
        for t in times:
            text += (f'[[trajectory.waypoint]]\nt = {{ value = {t}, unit = "s", source = "probe" }}\n'
                     f'eta = {{ value = [0, 0, 0, 0, 0, 0], unit = "m,m,m,rad,rad,rad", source = "probe" }}\n')
    (d / "s.toml").write_text(text)
    rc, out, err = cli("simulate", "--system", "bluerov2_heavy_alpha5", "--controller", "agsta", "--config",
                          d / "s.toml", "--out", d / "r.h5")
    need(rc in (0, 2), f"exit {rc}: {err.strip()[-300:]}")
    lines = [ln for ln in err.splitlines() if "after the run's end" in ln]
    need(lines, f"no warning: {err.strip()[-300:]}")
    need(re.search(r"\d+ s", lines[0]) and "time.duration" in lines[0], f"no time or length: {lines[0]}")
    return lines[0]


for _k in ("arm waypoint after the end", "task entirely after the end", "task waypoint after the end"):
    case(7, f"simulate --config: {_k}")(lambda k=_k: scenario_warn(k))


# the log readers: checked and reported only (their owner fixes them)

def _extra_field(data: bytes) -> bytes:
    """A decimal comma in row 40: one field more than the header."""
    lines = data.decode().splitlines(True)
    lines[40] = lines[40].replace("0.", "0,", 1)
    return "".join(lines).encode()


def log_case(kind: str) -> str:
    path, _trials = ident_inputs()
    d = WORK / "logs_bad" / re.sub(r"\W+", "_", kind)
    d.mkdir(parents=True)
    said = "xyzw" if kind == "quaternion order wrong" else "wxyz"  # the file holds w, x, y, z
    spoil = {"row with more fields than the header": _extra_field,
             "corrupt gzip": lambda raw: raw[: len(raw) // 2]}.get(kind)
    pose_log(d, 0.3, "wxyz", said, gz=kind == "corrupt gzip", spoil=spoil)
    rc, _o, err = cli("validate", "--system", path, d / "trial.log.toml", "--out", d / "v")
    word = {"quaternion order wrong": "quaternion", "row with more fields than the header": "row",
            "corrupt gzip": "gzip"}[kind]
    return one_line(rc, err, word)


for _k in ("quaternion order wrong", "row with more fields than the header", "corrupt gzip"):
    case(7, f"validate (log reader, check only): {_k}")(lambda k=_k: log_case(k))


# ---- the run -------------------------------------------------------------------------------------------

def scrub(text: str) -> str:
    """No machine paths in the record."""
    text = text.replace(str(WORK), "<probe>").replace(str(ROOT), "<repo>")
    return re.sub(r"/tmp/[^\s'\"]*", "<tmp>", text.replace(os.path.expanduser("~"), "~"))


def main(argv=None) -> int:
    global WORK
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="items to run, e.g. 4,5,7 (default every item)")
    ap.add_argument("--match", default="", help="only cases whose name holds this text")
    ap.add_argument("--out", default=str(ROOT / "results" / "probe"), help="where probe.json and probe.md go")
    ap.add_argument("--keep", action="store_true", help="keep the working directory")
    ap.add_argument("--merge", action="store_true", help="replace only the cases run in an existing probe.json")
    a = ap.parse_args(argv)
    items = {int(x) for x in a.only.split(",") if x}
    WORK = Path(tempfile.mkdtemp(prefix="arvcas-probe-"))
    rows = []
    try:
        for item, name, fn in CASES:
            if (items and item not in items) or a.match not in name:
                continue
            t0 = time.monotonic()
            try:
                msg, ok = fn(), True
            except Probe as e:
                msg, ok = str(e), False
            except Exception as e:  # noqa: BLE001 - the probe's own failure is a FAIL too
                msg, ok = f"probe raised {type(e).__name__}: {e}", False
            row = {"item": item, "case": name, "verdict": "PASS" if ok else "FAIL",
                   "message": scrub(str(msg)).strip().splitlines()[0][:400] if str(msg).strip() else "",
                   "seconds": round(time.monotonic() - t0, 1)}
            rows.append(row)
            print(f"{row['verdict']}  {item}  {name}: {row['message']}", flush=True)
    finally:
        if not a.keep:
            shutil.rmtree(WORK, ignore_errors=True)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.merge and (out / "probe.json").exists():  # the earlier rows, with the cases run now replaced
        new = {(r["item"], r["case"]): r for r in rows}
        old = json.loads((out / "probe.json").read_text(encoding="utf-8"))["rows"]
        rows = [new.pop((r["item"], r["case"]), r) for r in old] + list(new.values())
    import arvcas

    n_fail = sum(r["verdict"] == "FAIL" for r in rows)
    doc = {"arvcas_version": arvcas.__version__, "cases": len(rows), "failed": n_fail, "rows": rows}
    (out / "probe.json").write_text(json.dumps(doc, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    md = ["# The hostile probe", "", f"`python tests/probe_cases.py` (arvcas {arvcas.__version__}): "
          f"{len(rows)} cases, {n_fail} failed.", "", "| item | case | verdict | what the command said |",
          "|---|---|---|---|"]
    md += [f"| {r['item']} | {r['case'].replace('|', '/')} | {r['verdict']} | "
           f"{r['message'].replace('|', '/').replace('<', '&lt;')} |" for r in rows]
    (out / "probe.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    print(f"{len(rows)} cases, {n_fail} failed; {out / 'probe.json'}")
    return 1 if n_fail else 0


if __name__ == "__main__":
    sys.exit(main())
