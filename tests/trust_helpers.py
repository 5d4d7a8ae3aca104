"""Shared by tests/test_trust_*.py and the other tests of what a user gets wrong, and by the hostile probe
(tests/probe_cases.py): run the CLI, snapshot a directory, a small synthetic front.h5, names that are markup,
a page in headless Chromium, a plugin law that returns the wrong thing, an attitude log with its mapping, xacro
that expands without end."""

from __future__ import annotations

import gzip
import html
import os
import re
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import numpy as np

from arvcas import cli
from arvcas.util.files import TMP_MARK


def bounded(fn, timeout: float = 120.0):
    """``fn()`` in a thread that must end within ``timeout`` s (a hang fails the test, not the run); returns
    the exception it raised, or None."""
    box = {}

    def target():
        try:
            fn()
        except BaseException as e:  # noqa: BLE001 - returned
            box["e"] = e

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(timeout)
    assert not t.is_alive(), f"did not return within {timeout} s"
    return box.get("e")


def run(argv, capsys, timeout: float = 300.0):
    """``cli.main(argv)`` in a thread that must end within ``timeout``; returns (exit code, stderr)."""
    rc, _out, err = run3(argv, capsys, timeout)
    return rc, err


def run3(argv, capsys, timeout: float = 300.0):
    """``cli.main(argv)`` in a thread that must end within ``timeout`` (a hang fails the test, not the run);
    returns (exit code, stdout, stderr)."""
    box = {}

    def target():
        try:
            box["rc"] = cli.main([str(a) for a in argv])
        except BaseException as e:  # noqa: BLE001 - reported below
            box["exc"] = e

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(timeout)
    assert not t.is_alive(), f"arvcas {' '.join(map(str, argv))} did not return within {timeout} s"
    if "exc" in box:
        raise box["exc"]
    cap = capsys.readouterr()
    return box["rc"], cap.out, cap.err


def snapshot(d) -> dict:
    """name -> (bytes, mtime_ns) of every file below ``d`` (FIFOs and devices: their mode only)."""
    out = {}
    for root, _dirs, names in os.walk(d):
        for n in names:
            p = Path(root) / n
            st = os.lstat(p)
            if p.is_file() and not p.is_symlink():
                out[str(p.relative_to(d))] = (p.read_bytes(), st.st_mtime_ns)
            else:
                out[str(p.relative_to(d))] = (st.st_mode, None)
    return out


def assert_refused(argv, capsys, d, message: str, timeout: float = 300.0) -> str:
    """Exit code 2, one line naming ``message``, nothing under ``d`` changed, no temporary file left."""
    before = snapshot(d)
    rc, err = run(argv, capsys, timeout)
    assert rc == 2, (argv, err)
    assert err.count("\n") == 1 and err.startswith("arvcas: error: ") and "Traceback" not in err, err
    assert message in err, (message, err)
    after = snapshot(d)
    assert after == before, sorted(set(after) ^ set(before)) or "a file's bytes or mtime changed"
    assert not [k for k in after if TMP_MARK in k], after
    return err


def synthetic_front(path: Path, *, model_hash: str | None = None, params=None, controller: str = "agsta",
                    run_digest: str = "") -> Path:
    """A finished three-member front.h5 written by arvcas's checkpoint writer (no tuning run); ``model_hash``
    default today's, ``run_digest`` default none (valid by the model hash alone)."""
    from arvcas.build.provenance import model_hash as current_hash
    from arvcas.controllers import gains as gains_mod
    from arvcas.system.params import load
    from arvcas.sim.scenario import load_scenario
    from arvcas.tuning import checkpoint as ck

    cfg = load_scenario()
    names = gains_mod.gain_names(controller)
    g0 = gains_mod.default_gains(controller)
    m, n = len(names), 3
    X = np.log10(np.vstack([g0 * f for f in (0.9, 1.0, 1.1)]))
    F = np.array([[0.8, 1.3], [1.0, 1.0], [1.2, 0.8]])
    c = ck.Checkpoint(
        controller=controller, study_name="synthetic", study_text="", study_path="", identity="{}",
        scenario_text=cfg.text, seed=0, names=list(names), lower=g0 / 2, upper=g0 * 2, table2=g0,
        draw_seeds=np.array([0], dtype=np.int64), draw_uncertainty=np.array([cfg.uncertainty], dtype=float),
        draw_phase=np.array([cfg.disturbance_phase], dtype=float),
        params=load().vector() if params is None else np.asarray(params, float),
        reference_point=np.array([2.0, 2.0]), status="finished", stop_reason="test", n_gen=1, n_eval=n,
        X=X, gains=10.0 ** X, F=F, G=np.full((n, 1), -1.0), rank=np.zeros(n), crowding=np.full(n, np.inf),
        chat=np.ones((1, n, 6)), rmse=np.ones((1, n, 6)), ok=np.ones((1, n), bool), t_fail=np.full((1, n), np.nan),
        history={k: np.ones(1) for k in ck.HISTORY_FIELDS},
        table2_F=np.array([1.0, 1.0]), table2_G=np.array([-1.0]), table2_chat=np.ones((1, 6)),
        table2_rmse=np.ones((1, 6)), table2_ok=np.ones(1, bool), table2_t_fail=np.full(1, np.nan),
        versions=ck.versions(), model_hash=current_hash() if model_hash is None else model_hash,
        run_digest=run_digest,
    )
    assert X.shape == (n, m)
    return ck.write_checkpoint(c, path)


def scenario_variant(tmp_path: Path, old: str, new: str, name: str = "s.toml") -> Path:
    """The BlueROV2's shipped scenario with the text ``old`` replaced by ``new`` (once), written to tmp_path."""
    from arvcas.system import shipped

    src = shipped()["bluerov2_heavy_alpha5"].parent / "bluerov2_heavy_alpha5.scenario.toml"
    text = src.read_text()
    assert old in text, old
    p = tmp_path / name
    p.write_text(text.replace(old, new, 1))
    return p


# names a user controls (study, system, controller, objective, gain and file names, descriptions): each one is
# text on a page, never markup; these break an inline script block or run code if they reach it unescaped
HOSTILE = ("x<!--<script>y", "</script><script>document.body.setAttribute('data-pwned','1')</script>",
           "<img src=x onerror=\"document.body.setAttribute('data-pwned','2')\">", "a&amp;b\"'<!--")


def chromium(args, timeout: float = 120.0):
    """Headless Chromium (the Debian package) on a fresh profile with ``args``: the completed process, or None
    when Chromium is not installed."""
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        return None
    with tempfile.TemporaryDirectory() as profile:
        return subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                               "--disable-background-networking", "--disable-component-update", "--disable-sync",
                               f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0",
                               "--virtual-time-budget=5000", *args],
                              capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)


def page_faults(dom: str, stderr: str, payload: str | None = None) -> list[str]:
    """What is wrong with a page Chromium loaded (its ``--dump-dom`` and its stderr): a console line, its script
    not run to the end, a script that a name carried ran, ``payload`` (if given) not shown as text. Empty when
    nothing is."""
    console = [ln for ln in stderr.splitlines() if ":CONSOLE" in ln]
    faults = [f"console: {console[:1]}"] if console else []
    if 'data-ready="1"' not in dom or '<p id="status">ready</p>' not in dom:
        faults.append("the page's script did not run to the end (still loading, or an error)")
    if re.search(r'data-pwned="\d"', dom):
        faults.append("a script the name carried ran")
    if payload is not None and html.escape(payload, quote=False) not in dom:
        faults.append("the name is not shown as text")
    return faults


# a plugin law whose initial or step returns what ``initial`` and ``step`` say (Python source of one line
# each); the step's line is line 17 of the file (a raise there names it)
BAD_LAW = '''\
import casadi as ca
import arvcas


class Bad(arvcas.Controller):
    name = "{name}"
    gains = (arvcas.Gain("k", "1/s", "gain"),)
    defaults = [1.0] * 6
    defaults_block = "{block}"
    state = (("w", 6),)

    def initial(self, ctx, G):
        {initial}

    def step(self, ctx, G, x):
        tau = -G["k"] * ctx.e
        {step}
'''
GOOD_INITIAL = 'return {"w": ca.DM.zeros(6)}'
GOOD_STEP = "return tau, x"


def bad_law(name: str, step: str = GOOD_STEP, initial: str = GOOD_INITIAL, block: str | None = None) -> str:
    """The source of the plugin law ``name`` (its gain table's block ``block``, default its name) whose
    ``initial`` and ``step`` end in the given lines."""
    return BAD_LAW.format(name=name, block=block or name, initial=initial, step=step)


def pose_log(d: Path, yaw0: float, file_order: str, said_order: str, accel: bool = True, gz: bool = False,
             spoil=None) -> Path:
    """``d/trial.log.toml`` and its pose stream (NED, FRD; 20 s at 50 Hz, ``yaw0`` the heading at the start)
    whose quaternion the file holds in ``file_order`` and the mapping calls ``said_order``; with ``accel``, the
    accelerometer's specific force at rest plus 0.3 m/s^2 of motion. ``gz``: the stream gzip-compressed;
    ``spoil``: a function of the stream file's bytes that returns the bytes written (a damaged file)."""
    from scipy.spatial.transform import Rotation

    t = np.arange(0.0, 20.0 + 1e-9, 0.02)
    rng = np.random.default_rng(1)
    e = np.stack([0.1 * np.sin(0.7 * t), 0.08 * np.cos(0.5 * t), yaw0 + 0.02 * t], axis=1)
    Rm = Rotation.from_euler("ZYX", e[:, ::-1])
    q = Rm.as_quat()  # x, y, z, w
    if file_order == "wxyz":
        q = q[:, [3, 0, 1, 2]]
    cols, hdr = [t, *q.T], ["t", "q0", "q1", "q2", "q3"]
    if accel:
        f = -9.80665 * Rm.as_matrix()[:, 2, :] + 0.3 * rng.standard_normal((len(t), 3))
        cols += list(f.T)
        hdr += ["ax", "ay", "az"]
    name = "pose.csv.gz" if gz else "pose.csv"
    text = ",".join(hdr) + "\n" + "\n".join(",".join(f"{v:.12g}" for v in row) for row in np.stack(cols, 1)) + "\n"
    data = gzip.compress(text.encode()) if gz else text.encode()
    (d / name).write_bytes(spoil(data) if spoil else data)
    acc = 'acceleration = { columns = ["ax", "ay", "az"], unit = "m/s^2" }\n' if accel else ""
    (d / "trial.log.toml").write_text(f'''[log]
name = "trial"
passive = true
rate = 25.0

[[stream]]
file = "{name}"
time = "t"
world = "ned"
body = "frd"
quaternion_order = "{said_order}"
quaternion = {{ columns = ["q0", "q1", "q2", "q3"] }}
{acc}''')
    return d / "trial.log.toml"


# xacro that expands without end (``import-system uuv`` stops each in one line): a macro bomb, a macro that calls
# itself, and one expression that runs without end inside Python (no element is counted meanwhile): an integer
# power tower, a property that doubles itself 60 times (2^61 characters), a repetition of 10^12 characters
XACRO_HEAD = '<?xml version="1.0"?>\n<robot name="r" xmlns:xacro="http://www.ros.org/wiki/xacro">\n'


def xacro_bomb(levels: int) -> str:
    """Macro i calls macro i-1 twice: 2^levels links."""
    body = '  <xacro:macro name="m0"><link name="l"/></xacro:macro>\n'
    body += "".join(f'  <xacro:macro name="m{i}"><xacro:m{i - 1}/><xacro:m{i - 1}/></xacro:macro>\n'
                    for i in range(1, levels + 1))
    return XACRO_HEAD + body + f"  <xacro:m{levels}/>\n</robot>\n"


XACRO_RECURSIVE = XACRO_HEAD + ('  <xacro:macro name="r" params="n"><link name="l${n}"/><xacro:r n="${n+1}"/>'
                                '</xacro:macro>\n  <xacro:r n="0"/>\n</robot>\n')
XACRO_EXPRESSIONS = {
    "tower": XACRO_HEAD + '  <link name="${10**10**10}"/>\n</robot>\n',
    "doubling": XACRO_HEAD + '  <xacro:property name="p0" value="xx"/>\n' + "".join(
        f'  <xacro:property name="p{i}" value="${{p{i - 1}}}${{p{i - 1}}}"/>\n' for i in range(1, 61))
    + '  <link name="${p60}"/>\n</robot>\n',
    "repeat": XACRO_HEAD + '  <link name="${\'x\' * 10**12}"/>\n</robot>\n',
}
