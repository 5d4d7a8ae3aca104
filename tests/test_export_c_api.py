"""The exported controller's C API under AddressSanitizer and UBSan: a small C driver, compiled with the
exported library's source and ``-fsanitize=address,undefined``, calls every function with NULL pointers and
with physically impossible parameters (a negative mass or inertia, no water, a negative nominal-model factor,
a pitch set point at 90 deg, each entry of p against its sign rule) and checks the documented error codes
and bad_index; then a good init and steps. Any sanitizer report fails the run (-fno-sanitize-recover).
A Hypothesis property over the params (through the ctypes binding) checks init's verdict against the
same rules written in Python."""

from __future__ import annotations

import math
import shutil
import subprocess

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import arvcas
from arvcas import cli

from make_helpers import make_cmd

CC = shutil.which("cc") or shutil.which("gcc")

DRIVER = r"""
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "@LIB@.h"

#define CHECK(cond) do { if (!(cond)) { printf("FAIL line %d: %s\n", __LINE__, #cond); return 1; } } while (0)

static const int rules[@UP@N_P] = {@RULES@};

int main(void) {
  @P@params prm;
  @P@state s;
  double y[12] = {0}, u[@UP@N_U];
  int i, n_ekf, off_unc, off_ekf, off_eta, off_p, checked = 0;
  memset(&s, 0, sizeof s);
  @P@default_params(&prm);
  n_ekf = (int)(sizeof prm.ekf / sizeof prm.ekf[0]);
  off_unc = @UP@N_GAINS; off_ekf = off_unc + 4; off_eta = off_ekf + n_ekf; off_p = off_eta + 6;
  /* NULL pointers: documented codes, nothing dereferenced */
  @P@default_params(NULL);
  CHECK(@P@init(NULL, NULL) == @UP@E_NULL);
  CHECK(@P@step(NULL, NULL, 0.0, NULL, NULL) == @UP@E_NULL);
  CHECK(@P@error(12345) != NULL && @P@error(-12345) != NULL);
  CHECK(@P@init(NULL, &prm) == @UP@E_NULL);
  CHECK(@P@init(&s, NULL) == @UP@E_NULL);
  CHECK(@P@step(NULL, y, 0.0, NULL, u) == @UP@E_NULL);
  CHECK(@P@step(&s, NULL, 0.0, NULL, u) == @UP@E_NULL);
  @P@reset(NULL);
  CHECK(@P@diagnostics(NULL) == NULL);
  CHECK(@P@bad_index(NULL) == -1);
#if @UP@HAS_COMMAND_MAP
  CHECK(@P@command(NULL) == NULL);
#endif
  CHECK(@P@step(&s, y, 0.0, NULL, u) == @UP@E_NOT_INIT);
  CHECK(strcmp(@P@error(@UP@E_NULL), "unknown error code") != 0);
  /* impossible parameters: E_PARAM, bad_index names the entry, the state stays uninitialised */
  prm.unc[1] = -0.1;
  CHECK(@P@init(&s, &prm) == @UP@E_PARAM && @P@bad_index(&s) == off_unc + 1);
  @P@default_params(&prm);
  prm.eta_d[4] = 1.5707963267948966;
  CHECK(@P@init(&s, &prm) == @UP@E_PARAM && @P@bad_index(&s) == off_eta + 4);
  prm.eta_d[4] = -2.0;
  CHECK(@P@init(&s, &prm) == @UP@E_PARAM && @P@bad_index(&s) == off_eta + 4);
  @P@default_params(&prm);
  for (i = 0; i < @UP@N_P; ++i) {
    if (!rules[i]) continue;
    @P@default_params(&prm);
    prm.p[i] = rules[i] == 1 ? 0.0 : -1e-3;
    CHECK(@P@init(&s, &prm) == @UP@E_PARAM && @P@bad_index(&s) == off_p + i);
    prm.p[i] = -5.0;
    CHECK(@P@init(&s, &prm) == @UP@E_PARAM && @P@bad_index(&s) == off_p + i);
    checked++;
  }
  CHECK(@P@step(&s, y, 0.0, NULL, u) == @UP@E_NOT_INIT);
  /* a good init and steps */
  @P@default_params(&prm);
  CHECK(@P@init(&s, &prm) == 0 && @P@bad_index(&s) == -1);
  for (i = 0; i < 50; ++i) {
    y[0] = 0.01 * i;
    CHECK(@P@step(&s, y, 0.1 * i, NULL, i % 2 ? u : NULL) == 0);
    CHECK(isfinite(u[0]) && isfinite(@P@diagnostics(&s)[0]));
  }
  @P@reset(&s);
  CHECK(@P@step(&s, y, 0.0, NULL, u) == 0);
  printf("ok %d\n", checked);
  return 0;
}
"""


def _rules(params) -> list[int]:
    """The sign rules the exported init enforces: the layout's, and water density > 0 where there is water."""
    lay = params.layout
    out = [{"pos": 1, "nonneg": 2}.get(r, 0) for r in lay.rules]
    if "env.rho" in lay.names and params["env.rho"] > 0:
        out[lay.names.index("env.rho")] = 1
    return out


@pytest.fixture(scope="module", params=[("haidou1", "pid"), ("bluerov2_heavy_alpha5", "agsta")],
                ids=lambda c: f"{c[0]}-{c[1]}")
def exported(request, tmp_path_factory):
    if CC is None:
        pytest.skip("no C compiler")
    name, law = request.param
    d = tmp_path_factory.mktemp(f"capi_{name}")
    assert cli.main(["export-controller", str(d / "out"), "--controller", law, "--system", name]) == 0
    return name, law, d / "out", arvcas.load_system(name).params


def test_the_c_api_under_address_and_undefined_behaviour_sanitizers(exported):
    name, law, out, params = exported
    lib = next(p.stem for p in out.glob("*_params.h")).removesuffix("_params")
    pre = lib + "_"
    rules = _rules(params)
    src = (DRIVER.replace("@LIB@", lib).replace("@UP@", pre.upper()).replace("@P@", pre)
           .replace("@RULES@", ", ".join(map(str, rules))))
    (out / "driver.c").write_text(src)
    exe = out / "driver"
    # -O0: the sanitizers check the same accesses and operations (the optimiser removes none of them); at -O1
    # the BlueROV2's 400 kB of generated C took minutes to compile under them
    r = subprocess.run([CC, "-std=c99", "-g", "-O0", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                        "-fno-omit-frame-pointer", "-o", str(exe), "driver.c", f"{lib}.c", "-lm"],
                       cwd=out, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    r = subprocess.run([str(exe)], capture_output=True, text=True, timeout=300,
                       env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0", "UBSAN_OPTIONS": "print_stacktrace=1"})
    assert r.returncode == 0 and "runtime error" not in r.stderr and "ERROR:" not in r.stderr, \
        (r.stdout[-2000:], r.stderr[-3000:])
    assert r.stdout.strip() == f"ok {sum(1 for x in rules if x)}"
    assert sum(1 for x in rules if x) >= 7  # masses, inertias, g, the water's density at least


@pytest.fixture(scope="module")
def binding(exported):
    from arvcas.export.closeloop import load_binding

    name, law, out, params = exported
    r = subprocess.run(make_cmd(out, f"lib{next(out.glob('*_params.h')).stem.removesuffix('_params')}.so"),
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    mod, ctl = load_binding(out)
    return mod, ctl, params


@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_init_accepts_exactly_what_the_rules_allow(binding, data):
    """Property: for params drawn around the defaults (entries scaled by any sign and size, NaN, inf), init
    succeeds exactly when the Python statement of the rules holds, and a refusal names the first bad entry."""
    mod, ctl, params = binding
    dflt = ctl.defaults()
    rules = _rules(params)
    vals = {k: list(np.atleast_1d(np.asarray(dflt[k], float))) for k in ("unc", "eta_d", "p")}
    special = st.sampled_from([0.0, -1.0, float("nan"), float("inf"), 1e300])
    for key in ("unc", "eta_d", "p"):
        n = len(vals[key])
        for _ in range(data.draw(st.integers(0, 2))):
            i = data.draw(st.integers(0, n - 1))
            vals[key][i] = data.draw(special | st.floats(-10, 10).map(lambda f, v=vals[key][i]: v * f))
    first = None
    for key, ok in (("unc", lambda v, i: math.isfinite(v) and v >= 0),
                    ("eta_d", lambda v, i: math.isfinite(v) and (i != 4 or abs(v) < math.pi / 2)),
                    ("p", lambda v, i: math.isfinite(v) and (rules[i] != 1 or v > 0) and (rules[i] != 2 or v >= 0))):
        for i, v in enumerate(vals[key]):
            if first is None and not ok(v, i):
                first = (key, i)
    try:
        ctl.init(gains=dflt["gains"], ekf=dflt["ekf"], **vals)
    except mod.ControllerError as e:
        if first is None:  # passed the rules: only the derived terms (e.g. a singular thruster matrix) may fail
            assert "derived terms" in str(e), e
        else:
            assert str(e).endswith(f": {first[0]}[{first[1]}]"), (first, e)
        return
    finally:
        ctl.init(**dflt)
    assert first is None
