"""The build cache of arvcas.build.codegen: generated C against the SX graph, reuse across processes,
concurrent builds, tampered artifacts, unsafe directories and flags.

Every test runs against a temporary cache (``ARVCAS_CACHE``). The five plant functions are compiled
once per module; the cache-mechanics tests use a small toy function so they stay fast. Tolerance
for C against CasADi's VM: 1e-12 relative to the largest output entry.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import logging
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from arvcas.build import codegen as C
from arvcas.build.dynamics import compiled
from arvcas.model import uvms
from arvcas.system.params import load

RTOL = 1e-12

# The toy function, as source so child processes define exactly the same graph.
TOY_SRC = textwrap.dedent(
    """
    import casadi as ca

    def make_toy(name, c):
        x, y, z = ca.SX.sym("x", 3), ca.SX.sym("y", 2), ca.SX.sym("z")
        r = ca.vertcat(ca.sin(x[0]) * y[0] + c, x[1] * x[2] - ca.sqrt(1 + y[1] ** 2), ca.exp(z) * x[0] / c)
        return ca.Function(name, [x, y, z], [r], ["x", "y", "z"], ["r"])

    TOY_IN = ([0.3, -1.2, 2.5], [1.5, -0.7], 0.4)
    """
)
_ns: dict = {}
exec(TOY_SRC, _ns)
make_toy, TOY_IN = _ns["make_toy"], _ns["TOY_IN"]


def toy_ref(c: float) -> np.ndarray:
    return np.asarray(make_toy("toy_ref", c)(*TOY_IN)).ravel()


def run_child(cache: Path, body: str, timeout: float = 120) -> dict:
    """Run ``body`` in a fresh Python process with ARVCAS_CACHE=cache; it prints one JSON line."""
    code = TOY_SRC + "\nimport json, sys, time\nfrom arvcas.build import codegen as C\n" + textwrap.dedent(body)
    env = dict(os.environ, ARVCAS_CACHE=str(cache))
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


CHILD_TOY = """
f = C.build(make_toy({name!r}, {c!r}))
print(json.dumps({{"stats": C.stats(), "r": [float(v) for v in f(*TOY_IN).full().ravel()],
                  "path": C.artifact_of(f)["path"]}}))
"""


def sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def manifest_of(so: Path) -> dict:
    return json.loads(so.with_suffix(".json").read_text())


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    d = tmp_path / "cache"
    monkeypatch.setenv("ARVCAS_CACHE", str(d))
    return d


@pytest.fixture(scope="module")
def plant():
    return uvms.plant_functions(uvms.ModelOptions())


@pytest.fixture(scope="module")
def built(cache, plant):
    """The five plant functions compiled at the default level into the module's cache (the slow part: seconds)."""
    return {name: C.build(plant[name]) for name in uvms.PUBLIC_FUNCTIONS}


def random_inputs(f: ca.Function, rng: np.random.Generator, p0: np.ndarray) -> list:
    args = []
    for i, name in enumerate(f.name_in()):
        n = f.numel_in(i)
        if name == "p":
            args.append(p0 * (1 + 0.01 * rng.standard_normal(n)))  # keeps every sign rule
        elif name == "payload":
            args.append(rng.uniform(0, 1, n))
        elif name == "u":
            args.append(rng.uniform(-300, 300, n))  # beyond both thrust limits
        elif name == "tau":
            args.append(rng.uniform(-200, 200, n))
        else:
            args.append(rng.uniform(-0.6, 0.6, n))
    return args


# ---- compiled C against the SX graph ---------------------------------------------------------


@pytest.mark.parametrize("name", uvms.PUBLIC_FUNCTIONS)
def test_compiled_matches_sx(name, built, plant, cache):
    f_c, f_sx = built[name], plant[name]
    assert f_c.is_a("External") and not f_sx.is_a("External")
    assert f_c.name_in() == f_sx.name_in() and f_c.name_out() == f_sx.name_out()
    art = C.artifact_of(f_c)
    assert Path(art["path"]).parent == cache and sha256(art["path"]) == art["so_sha256"]
    rng = np.random.default_rng(20240611 + len(name))
    p0 = load().vector()
    for _ in range(6):
        args = random_inputs(f_sx, rng, p0)
        ref = np.asarray(f_sx(*args)).ravel()
        got = np.asarray(f_c(*args)).ravel()
        assert np.all(np.isfinite(ref))
        np.testing.assert_allclose(got, ref, rtol=RTOL, atol=RTOL * np.max(np.abs(ref)))


def test_manifest_contents(built, cache):
    so = Path(C.artifact_of(built["uvms_rhs"])["path"])
    m = manifest_of(so)
    assert so.name == f"uvms_rhs-{m['key'][:20]}.so"
    assert m["so_sha256"] == sha256(so)
    assert m["flags"][:3] == ["-shared", "-fPIC", C.default_opt_level()]
    assert m["casadi_version"] == ca.__version__
    assert m["compile_time_s"] > 0
    d, arts = C.cache_info()
    assert d == cache
    assert {a.name for a in arts} == set(uvms.PUBLIC_FUNCTIONS) and all(a.verified for a in arts)


def test_second_process_reuses_artifact(built, cache):
    so = Path(C.artifact_of(built["uvms_rhs"])["path"])
    man = so.with_suffix(".json")
    before = (os.stat(so).st_mtime_ns, os.stat(so).st_ino, os.stat(man).st_mtime_ns)
    x = [0.1 * i for i in range(12)]
    out = run_child(
        cache,
        f"""
        import numpy as np
        from arvcas.system.params import load
        from arvcas.model.uvms import plant_functions
        t0 = time.perf_counter()
        f = C.build(plant_functions()["uvms_rhs"])  # keyed by its C text, as the module's fixture built it
        dt = time.perf_counter() - t0
        xdot = f({x!r}, [10, 0, 5, 0, 0, 1], [1.5, 1.5, -1.5, 0, 1.5, 0], [0.1] * 6, [0] * 6, 0.5, load().vector())
        print(json.dumps({{"stats": C.stats(), "path": C.artifact_of(f)["path"], "load_s": dt,
                          "xdot": [float(v) for v in xdot.full().ravel()]}}))
        """,
    )
    assert out["stats"]["compile"] == 0 and out["stats"]["disk_hit"] == 1
    assert out["path"] == str(so)
    assert (os.stat(so).st_mtime_ns, os.stat(so).st_ino, os.stat(man).st_mtime_ns) == before
    mine = built["uvms_rhs"](x, [10, 0, 5, 0, 0, 1], [1.5, 1.5, -1.5, 0, 1.5, 0], [0.1] * 6, [0] * 6, 0.5,
                             load().vector())
    assert out["xdot"] == [float(v) for v in mine.full().ravel()]  # the same library: bit for bit
    print(f"cache-hit compiled('uvms_rhs') in a new process: {out['load_s']:.3f} s")


# ---- cache mechanics on the toy function -----------------------------------------------------


def test_memo_does_not_rehash(fresh_cache, monkeypatch):
    f = make_toy("toy_memo", 1.0)
    lib = C.build(f)
    n = C.stats()

    def no_codegen(*a, **k):
        raise AssertionError("build() of a memoized Function generated C again")

    monkeypatch.setattr(C, "_plan", no_codegen)
    assert C.build(f) is lib
    s = C.stats()
    assert s["memo_hit"] == n["memo_hit"] + 1 and s["compile"] == n["compile"]


def test_compile_is_logged(fresh_cache, caplog):
    with caplog.at_level(logging.INFO, logger="arvcas.build.codegen"):
        C.build(make_toy("toy_log", 1.0))
    msgs = [r.getMessage() for r in caplog.records]
    assert any(m.startswith("compiling toy_log (") and "instructions)" in m and "done in" in m for m in msgs), msgs


def test_concurrent_builds_compile_once(fresh_cache):
    fresh_cache.mkdir(mode=0o700)
    barrier = fresh_cache.parent
    body = """
    import os
    me, other = os.path.join({b!r}, "ready-{i}"), os.path.join({b!r}, "ready-{j}")
    open(me, "w").close()
    while not os.path.exists(other):
        time.sleep(0.001)
    """
    code = TOY_SRC + "\nimport json, sys, time\nfrom arvcas.build import codegen as C\n"
    env = dict(os.environ, ARVCAS_CACHE=str(fresh_cache))
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", code + textwrap.dedent(body.format(b=str(barrier), i=i, j=1 - i))
             + CHILD_TOY.format(name="toy_conc", c=1.5)],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        for i in (0, 1)
    ]
    outs = []
    for p in procs:
        so, se = p.communicate(timeout=120)
        assert p.returncode == 0, se
        outs.append(json.loads(so.strip().splitlines()[-1]))
    assert sum(o["stats"]["compile"] for o in outs) == 1
    assert sum(o["stats"]["disk_hit"] for o in outs) == 1
    assert sum(o["stats"]["private"] for o in outs) == 0
    ref = toy_ref(1.5)
    for o in outs:
        np.testing.assert_allclose(o["r"], ref, rtol=RTOL)
    assert outs[0]["path"] == outs[1]["path"]
    so = Path(outs[0]["path"])
    assert manifest_of(so)["so_sha256"] == sha256(so)
    assert not [p for p in fresh_cache.iterdir() if p.name.startswith(".")]  # no temporary dirs left


def _replace_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.chmod(tmp, 0o755)
    os.replace(tmp, path)  # new inode: this process may have the old one mapped


@pytest.mark.parametrize("case", ["truncate", "flip", "foreign", "foreign_no_manifest", "manifest_other_key"])
def test_bad_artifact_is_rebuilt_not_loaded(case, fresh_cache):
    name = f"toy_{case}"
    so = Path(C.artifact_of(C.build(make_toy(name, 2.0)))["path"])
    good = manifest_of(so)
    data = so.read_bytes()
    if case == "truncate":
        _replace_bytes(so, data[: len(data) // 2])
    elif case == "flip":
        i = len(data) // 2
        _replace_bytes(so, data[:i] + bytes([data[i] ^ 0xFF]) + data[i + 1 :])
    elif case.startswith("foreign"):
        # a valid library of the same name computing something else (c = 7)
        other = Path(C.artifact_of(C.build(make_toy(name, 7.0)))["path"])
        assert other != so
        _replace_bytes(so, other.read_bytes())
        if case == "foreign_no_manifest":
            so.with_suffix(".json").unlink()
    elif case == "manifest_other_key":
        so.with_suffix(".json").write_text(json.dumps(dict(good, key="0" * 64)))
    assert sha256(so) != good["so_sha256"] or case == "manifest_other_key"

    out = run_child(fresh_cache, CHILD_TOY.format(name=name, c=2.0))
    assert out["stats"]["rejected"] == 1 and out["stats"]["compile"] == 1 and out["stats"]["disk_hit"] == 0
    np.testing.assert_allclose(out["r"], toy_ref(2.0), rtol=RTOL)  # the foreign library gives c = 7
    assert out["path"] == str(so)
    m = manifest_of(so)
    assert m["key"] == good["key"] and m["so_sha256"] == sha256(so)

    d, arts = C.cache_info()
    assert all(a.verified for a in arts if a.path == so)


def test_cache_info_flags_tampered(fresh_cache):
    so = Path(C.artifact_of(C.build(make_toy("toy_info", 1.0)))["path"])
    assert [a.verified for a in C.cache_info()[1]] == [True]
    _replace_bytes(so, so.read_bytes() + b"\0")
    assert [a.verified for a in C.cache_info()[1]] == [False]


def test_lock_timeout_builds_privately(fresh_cache, caplog):
    so = Path(C.artifact_of(C.build(make_toy("toy_lock", 3.0)))["path"])
    so.unlink()
    so.with_suffix(".json").unlink()
    fd = os.open(so.with_suffix(".lock"), os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # "another process" holds the build lock forever
        n = C.stats()
        with caplog.at_level(logging.WARNING, logger="arvcas.build.codegen"):
            f = C.build(make_toy("toy_lock", 3.0), lock_timeout=0.2)
    finally:
        os.close(fd)
    np.testing.assert_allclose(np.asarray(f(*TOY_IN)).ravel(), toy_ref(3.0), rtol=RTOL)
    assert C.stats()["private"] == n["private"] + 1
    assert C.artifact_of(f)["private"] is True and Path(C.artifact_of(f)["path"]) != so
    assert not so.exists()  # a private build is not published
    assert any("building toy_lock privately" in r.getMessage() for r in caplog.records)


# ---- refusals ------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", [0o770, 0o702, 0o777])
def test_group_or_other_writable_cache_is_refused(tmp_path, monkeypatch, mode):
    d = tmp_path / "shared"
    d.mkdir()
    os.chmod(d, mode)
    monkeypatch.setenv("ARVCAS_CACHE", str(d))
    with pytest.raises(C.CacheError, match=r"writable by group or others.*chmod go-w") as e:
        C.cache_dir()
    assert "\n" not in str(e.value) and isinstance(e.value, ValueError)
    with pytest.raises(C.CacheError):
        C.build(make_toy("toy_unsafe", 1.0))
    with pytest.raises(C.CacheError):
        C.cache_info()
    assert list(d.iterdir()) == []  # nothing written, nothing loaded


def test_cache_dir_default_location(tmp_path, monkeypatch):
    monkeypatch.delenv("ARVCAS_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    d = C.cache_dir()
    assert d == tmp_path / "xdg" / "arvcas"
    assert os.stat(d).st_mode & 0o777 == 0o700


@pytest.mark.parametrize(
    "kw", [{"opt_level": "-Ofast"}, {"flags": ("-ffast-math",)}, {"flags": ("-march=native", "-funsafe-math-optimizations")}]
)
def test_value_changing_flags_refused(fresh_cache, kw):
    n = C.stats()
    with pytest.raises(ValueError, match="changes the numbers"):
        C.build(make_toy("toy_fast", 1.0), **kw)
    assert C.stats()["compile"] == n["compile"]
    assert not fresh_cache.exists() or not any(fresh_cache.iterdir())


def test_bad_flag_types_refused(fresh_cache):
    with pytest.raises(ValueError, match="tuple of strings"):
        C.build(make_toy("toy_flags", 1.0), flags="-O3")
    with pytest.raises(ValueError, match="opt_level"):
        C.build(make_toy("toy_flags", 1.0), opt_level="O2")


def test_compiler_failure_is_one_line(fresh_cache):
    with pytest.raises(C.CompileError, match=r"cc failed compiling toy_cc \(exit \d+\)") as e:
        C.build(make_toy("toy_cc", 1.0), flags=("-include", "/nonexistent/arvcas.h"))
    assert "\n" not in str(e.value)
    assert [p.suffix for p in fresh_cache.iterdir()] == [".lock"]  # nothing published, no build dir left


def test_other_opt_level_is_another_artifact(fresh_cache):
    a = C.artifact_of(C.build(make_toy("toy_olevel", 1.0), opt_level="-O0"))
    b = C.artifact_of(C.build(make_toy("toy_olevel", 1.0), opt_level="-O1"))
    assert a["key"] != b["key"] and a["path"] != b["path"]
    assert "-O0" in a["flags"] and "-O1" in b["flags"]


def test_default_opt_level_from_the_environment(fresh_cache, monkeypatch):
    """ARVCAS_OPT_LEVEL sets the level of a build that names none (the tests' -O0); unset, -O2; a named level
    wins; a bad value is refused in one line naming the variable."""
    monkeypatch.delenv(C.OPT_LEVEL_ENV, raising=False)
    assert C.default_opt_level() == C.DEFAULT_OPT_LEVEL == "-O2"
    monkeypatch.setenv(C.OPT_LEVEL_ENV, "-O1")
    assert "-O1" in C.artifact_of(C.build(make_toy("toy_envlevel", 1.0)))["flags"]
    assert "-O0" in C.artifact_of(C.build(make_toy("toy_envlevel", 1.0), opt_level="-O0"))["flags"]
    monkeypatch.setenv(C.OPT_LEVEL_ENV, "-Ofast")
    with pytest.raises(ValueError, match=r"^ARVCAS_OPT_LEVEL='-Ofast': expected one of -O0, -O1, -O2") as e:
        C.build(make_toy("toy_envlevel", 2.0))
    assert "\n" not in str(e.value)


def test_compiled_unknown_name():
    with pytest.raises(ValueError, match="allowed: vehicle_rhs, arm_wrench, uvms_rhs, allocate, thrust"):
        compiled("uvms")
    with pytest.raises(ValueError, match="ModelOptions"):
        compiled("thrust", opts={"n_quad": 5})


def test_isa_flags_follow_the_cpu_and_the_environment(monkeypatch):
    """-mavx only where /proc/cpuinfo lists avx on x86-64 Linux; ARVCAS_ISA=baseline drops it; any
    other value is refused in one line naming the variable."""
    import platform

    monkeypatch.setattr(C, "_cpu_flags", lambda: frozenset({"fpu", "sse2", "avx"}))
    on_x86 = sys.platform == "linux" and platform.machine() in ("x86_64", "AMD64")
    assert C.supported_isa.__wrapped__() == (("-mavx",) if on_x86 else ())
    monkeypatch.setattr(C, "_cpu_flags", lambda: frozenset({"fpu", "sse2"}))
    assert C.supported_isa.__wrapped__() == ()
    monkeypatch.setenv("ARVCAS_ISA", "baseline")
    assert C.isa_flags() == () and not any(f in C._check_flags("-O2", ()) for f in ("-mavx",))
    monkeypatch.setenv("ARVCAS_ISA", "avx512")
    with pytest.raises(C.CacheError, match="ARVCAS_ISA='avx512': expected 'auto'") as e:
        C.isa_flags()
    assert "\n" not in str(e.value)
    monkeypatch.setenv("ARVCAS_ISA", "auto")
    assert C.isa_flags() == C.supported_isa()
    assert C._check_flags("-O2", ())[-2 - len(C.supported_isa()):-1] == [*C.FIXED_FLAGS[-1:], *C.supported_isa()]
