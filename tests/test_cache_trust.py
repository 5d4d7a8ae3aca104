"""The compile cache under hostile conditions: a build killed by SIGTERM leaves no compiler running and
no build directory; a cache where lock files cannot be created (read-only) still serves its verified
artifacts, without a false "lock busy" wait."""

from __future__ import annotations

import errno
import logging
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from arvcas.build import codegen, dynamics

SLOW_BUILD = """
import signal, sys
signal.signal(signal.SIGTERM, lambda *a: sys.exit(143))   # what a command line does: exit through finally blocks
import casadi as ca
from arvcas.build import codegen
x = ca.SX.sym("x", 40)
y = x
for i in range(400):                                       # ~50k instructions: seconds of cc at -O1
    y = ca.sin(y * 1.0001 + ca.cos(y[::-1])) + 1e-3 * i
codegen.build(ca.Function("slow_to_compile", [x], [y]))
"""


def _procs_mentioning(text: str) -> list[str]:
    out = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in cmd:
            out.append(f"{pid}: {cmd[:120]}")
    return out


def test_sigterm_during_a_cold_compile_kills_the_compiler_and_cleans_up(tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    child = subprocess.Popen([sys.executable, "-c", textwrap.dedent(SLOW_BUILD)],
                             env=dict(os.environ, ARVCAS_CACHE=str(cache)), stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not _procs_mentioning(str(cache)):  # the compiler has started
        if child.poll() is not None:
            pytest.fail(f"the build ended before it could be interrupted: {child.stderr.read()[-500:]}")
        time.sleep(0.02)
    assert _procs_mentioning(str(cache)), "no compiler process seen"
    time.sleep(0.3)
    child.send_signal(signal.SIGTERM)
    assert child.wait(timeout=30) == 143
    time.sleep(0.2)
    assert _procs_mentioning(str(cache)) == []  # no orphaned cc / cc1 / as
    assert [p.name for p in cache.iterdir() if p.name.startswith((".build-", ".private-"))] == []
    assert not list(cache.glob("*.so")) and not list(cache.glob("*.json"))  # nothing half-published


def test_cache_without_writable_lock_files_serves_verified_artifacts(tmp_path, monkeypatch, caplog):
    cache = tmp_path / "cache"
    monkeypatch.setenv("ARVCAS_CACHE", str(cache))
    monkeypatch.setattr(codegen, "_DESCRIBED", {})
    monkeypatch.setattr(dynamics, "_PLANT_COMPILED", {})
    f = dynamics.compiled("thrust")
    path = codegen.artifact_of(f)["path"]
    real_open = os.open

    def read_only(p, flags, *a, **k):  # as on a read-only file system: a new (lock) file cannot be made
        if str(p).endswith(".lock") and flags & (os.O_CREAT | os.O_RDWR | os.O_WRONLY):
            raise OSError(errno.EROFS, "Read-only file system", str(p))
        return real_open(p, flags, *a, **k)

    monkeypatch.setattr(codegen.os, "open", read_only)
    monkeypatch.setattr(codegen, "_DESCRIBED", {})
    monkeypatch.setattr(dynamics, "_PLANT_COMPILED", {})
    before = codegen.stats()
    with caplog.at_level(logging.INFO, logger=codegen.__name__):
        g = dynamics.compiled("thrust")
    after = codegen.stats()
    assert after["disk_hit"] == before["disk_hit"] + 1 and after["compile"] == before["compile"]
    assert codegen.artifact_of(g)["path"] == path
    assert not [r for r in caplog.records if "busy" in r.getMessage()]


def test_a_build_reports_its_progress_and_a_cache_hit_is_silent(tmp_path, monkeypatch, capsys):
    """report_progress: a build longer than the threshold writes one line, what it built and how long it
    took; the same build from the cache writes nothing (the command line reports at 1 s on stderr)."""
    import io

    import casadi as ca

    monkeypatch.setenv("ARVCAS_CACHE", str(tmp_path / "cache"))
    x = ca.SX.sym("x", 20)
    y = x
    for i in range(30):
        y = ca.sin(y * 1.001 + ca.cos(y[::-1])) + 1e-3 * i
    make = lambda: ca.Function("progress_probe", [x], [y])  # noqa: E731
    out = io.StringIO()
    with codegen.report_progress(out, after=0.0):
        f = codegen.build_described("progress_probe", "progress test", make, label="the probe for a test")
    assert f(ca.DM.ones(20)).shape == (20, 1)
    line = out.getvalue()
    assert line.startswith("arvcas: compiling the probe for a test ...") and line.endswith(" s\n"), line
    assert line.count("\n") == 1 and float(line.split("... ")[1].split(" s")[0]) > 0
    codegen._DESCRIBED.clear()  # a new process's view: the library is loaded from the disk cache
    out2 = io.StringIO()
    with codegen.report_progress(out2, after=0.0):
        codegen.build_described("progress_probe", "progress test", make, label="the probe for a test")
    assert out2.getvalue() == ""
    capsys.readouterr()
    codegen.build_described("progress_probe", "progress test 2", make)  # a build outside report_progress: silent
    assert capsys.readouterr() == ("", "")
