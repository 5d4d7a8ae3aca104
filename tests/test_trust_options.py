"""Options that do not apply are refused, not ignored; every command comes from the one table."""

from __future__ import annotations

from arvcas import cli

from test_tuning_study import write_tiny
from trust_helpers import assert_refused, synthetic_front


def test_every_command_is_declared_once_in_the_table():
    names = [c.name for c in cli.TABLE]
    assert len(names) == len(set(names)) and set(cli.COMMANDS) == set(names)
    assert {"simulate", "tune", "front export", "front plot", "front explore", "front robust", "compare", "sweep",
            "montecarlo", "paper", "bench", "export-c", "export-fmu", "cache", "demo", "systems", "knees",
            "validate", "identify", "export-controller", "import-system uuv", "controllers", "params", "front restamp"} == set(names)
    ap = cli._parser()
    for c in cli.TABLE:
        argv = c.name.split() + ["--help"]
        try:
            ap.parse_args(argv)
        except SystemExit as e:
            assert e.code == 0
    # every command that writes has --force, added by the table, not by its handler
    for c in cli.TABLE:
        sub = ap._subparsers._group_actions[0].choices[c.name.split()[0]]
        if " " in c.name:
            sub = sub._subparsers._group_actions[0].choices[c.name.split()[1]]
        has_force = any("--force" in a.option_strings for a in sub._actions)
        assert has_force == (c.outputs is not None), c.name


def test_options_that_do_not_apply(tmp_path, capsys):
    d = tmp_path
    front = synthetic_front(d / "front.h5")
    study = write_tiny(d / "s.toml")
    mcfile = d / "mc.h5"
    mcfile.write_bytes(b"")  # never read: refused first
    mc = ["montecarlo", "--controller", "agsta", "--runs", "2", "--out", d / "x.h5"]
    cases = [
        (["simulate", "--controller", "agsta", "--index", "1"], "--index: only with --from-front"),
        (["simulate", "--controller", "agsta", "--allow-model-change"], "--allow-model-change: only with --from-front"),
        (["simulate", "--from-front", front], "--from-front needs --index"),
        (mc + ["--index", "2"], "--index: only with --from-front"),
        (["montecarlo", "--check", mcfile, "--seed", "3"], "--seed: --check FILE re-runs"),
        (["montecarlo", "--check", mcfile, "--spread", "0.1"], "--spread: --check FILE re-runs"),
        (["montecarlo", "--draws-toml", "--runs", "2", "--out", d / "x.h5"], "--out: --draws-toml only prints"),
        (["montecarlo", "--draws-toml", "--runs", "2", "--controller", "agsta"], "--controller: --draws-toml"),
        (["sweep", "--check", mcfile, "--seeds", "1"], "--seeds: --check FILE re-runs"),
        (["sweep", "--check", mcfile, "--noise-scale", "0"], "--noise-scale: --check FILE re-runs"),
        (["compare", front, front, "--paper"], "--paper: only with --plot"),
        (["compare", front, front, "--report", d / "r.md"], "--report: only for Monte Carlo"),
        (["tune", study, "--out", d / "o", "--engine", "local", "--workers", "2"], "--workers: only with --engine dask"),
        (["tune", study, "--out", d / "o", "--engine", "local", "--timeout", "2"], "--timeout: only with --engine dask"),
        (["tune", study, "--out", d / "o", "--scheduler", "tcp://127.0.0.1:1", "--threads", "2"],
         "--threads: only with the local engine"),
        (["tune", study, "--out", d / "o", "--allow-model-change"], "--allow-model-change: only with --resume"),
        (["tune", study, "--out", d / "o", "--timeout", "5"], "--timeout: only with the dask engine (this run uses local)"),
        (["tune", study, "--out", d / "o", "--workers", "2"], "--workers: only with the dask engine"),
    ]
    for argv, msg in cases:
        assert_refused(argv, capsys, d, msg)
    assert not (d / "o").exists()
