"""Bounds: every count, seed, timeout and load given on the command line is range-checked, and the
memory a request would take is estimated and refused, before any work."""

from __future__ import annotations

import pytest

from arvcas.io import cliargs

from trust_helpers import assert_refused, synthetic_front

BIG = str(2**63)


def test_bounds(tmp_path, capsys):
    d = tmp_path
    front = synthetic_front(d / "front.h5")
    study = d / "s.toml"
    study.write_text("")  # never read: the arguments are refused first
    mc = ["montecarlo", "--controller", "agsta", "--out", d / "mc.h5"]
    cases = [
        (["simulate", "--controller", "proposed", "--seed", BIG], f"argument --seed: {BIG} is out of range"),
        (["simulate", "--controller", "proposed", "--seed", "-1"], "0 <= seed < 2**63"),
        (["simulate", "--controller", "proposed", "--seed", "1e3"], "expected an integer seed"),
        (["simulate", "--controller", "proposed", "--n-quad", "0"], "argument --n-quad: 0 is out of range"),
        (["simulate", "--controller", "proposed", "--n-quad", "100000"], "(allowed: 1..20)"),
        (["paper", "--out", d / "p", "--seed", BIG], "argument --seed"),
        (mc + ["--runs", "0"], "argument --runs: 0 is out of range"),
        (mc + ["--runs", "10000000000"], "(allowed: 1..1000000)"),
        (mc + ["--runs", "2", "--seed", BIG], "argument --seed"),
        (["sweep", "--h", "0.1", "--out", d / "sw", "--seeds", "0..1000000000000"], "more than 10000"),
        (["sweep", "--h", "0.1", "--out", d / "sw", "--seeds", f"0..{2**63}"], "more than 10000"),
        (["sweep", "--h", "0.1", "--out", d / "sw", "--seeds", f"{2**63},1"], "0 <= seed < 2**63"),
        (["sweep", "--h", "0.1", "--out", d / "sw", "--seeds=-3..2"], "0 <= seed < 2**63"),
        (["sweep", "--h", "0.1", "--out", d / "sw", "--noise-scale", "nan"], "--noise-scale"),
        (["front", "robust", front, "--runs", "0"], "argument --runs"),
        (["front", "robust", front, "--runs", "3", "--seed", BIG], "argument --seed"),
        (["tune", study, "--out", d / "t", "--threads", "0"], "argument --threads: 0 is out of range"),
        (["tune", study, "--out", d / "t", "--workers", "100000"], "argument --workers"),
        (["tune", study, "--out", d / "t", "--timeout", "nan"], "must be a finite number of seconds > 0"),
        (["tune", study, "--out", d / "t", "--timeout", "inf"], "must be a finite number of seconds > 0"),
        (["tune", study, "--out", d / "t", "--timeout", "-1"], "must be a finite number of seconds > 0"),
        (["tune", study, "--out", d / "t", "--timeout", "0"], "must be a finite number of seconds > 0"),
        (["bench", "--out", d / "b", "--wait-load", "-1"], "a load average is a finite number >= 0"),
        (["bench", "--out", d / "b", "--wait-load", "nan"], "a load average is a finite number >= 0"),
        (["bench", "--out", d / "b", "--wait-load", "inf"], "a load average is a finite number >= 0"),
    ]
    for argv, msg in cases:
        assert_refused(argv, capsys, d, msg)


def test_memory_estimate_refuses_before_allocating(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cliargs, "_total_memory", lambda: 64 * 2**20)  # a 64 MiB machine
    d = tmp_path
    front = synthetic_front(d / "front.h5")
    cases = [
        (["montecarlo", "--controller", "agsta", "--runs", "1000000", "--out", d / "mc.h5"], "montecarlo --runs"),
        (["front", "robust", front, "--runs", "1000000"], "front robust --runs"),
        (["sweep", "--h", "0.01,0.02", "--out", d / "sw", "--seeds", "0..9999"], "sweep: would need about"),
    ]
    for argv, msg in cases:
        err = assert_refused(argv, capsys, d, msg)
        assert "GiB" in err and "ask for less" in err


@pytest.mark.parametrize("text, ok", [("0", True), (str(2**63 - 1), True), (BIG, False), ("-1", False)])
def test_seed_edges(text, ok):
    import argparse

    if ok:
        assert cliargs.seed_arg(text) == int(text)
    else:
        with pytest.raises(argparse.ArgumentTypeError):
            cliargs.seed_arg(text)
