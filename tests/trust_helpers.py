"""Shared by tests/test_trust_*.py: run the CLI, snapshot a directory, a small synthetic front.h5."""

from __future__ import annotations

import os
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
