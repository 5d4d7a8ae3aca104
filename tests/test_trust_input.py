"""Input policy: regular files only (FIFOs, devices, directories refused by name, never blocking), a size
cap, a byte-order mark named as such; checked before any work."""

from __future__ import annotations

import os

import pytest

from arvcas.util import files
from arvcas.sim.scenario import default_scenario_path

from trust_helpers import assert_refused, synthetic_front


@pytest.fixture()
def specials(tmp_path):
    os.mkfifo(tmp_path / "fifo.toml")
    (tmp_path / "dir.toml").mkdir()
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + default_scenario_path().read_bytes())
    utf16 = tmp_path / "utf16.toml"
    utf16.write_bytes("x = 1\n".encode("utf-16"))
    big = tmp_path / "big.toml"
    with open(big, "wb") as fh:
        fh.truncate(files.MAX_TEXT_BYTES + 1)
    return tmp_path


def test_input_refusals(specials, capsys):
    d = specials
    fifo, folder = d / "fifo.toml", d / "dir.toml"
    sim = ["simulate", "--controller", "proposed"]
    cases = [
        (sim + ["--config", fifo], "is a FIFO (named pipe), expected a regular file"),
        (sim + ["--config", "/dev/zero"], "is a character device"),
        (sim + ["--config", folder], "is a directory"),
        (sim + ["--params", fifo], "is a FIFO"),
        (sim + ["--config", d / "bom.toml"], "byte-order mark (UTF-8 with a BOM)"),
        (sim + ["--config", d / "utf16.toml"], "byte-order mark (UTF-16 (little-endian))"),
        (sim + ["--config", d / "big.toml"], f"more than the {files.MAX_TEXT_BYTES}-byte limit"),
        (sim + ["--config", d / "missing.toml"], "not found"),
        (["tune", fifo, "--out", d / "out"], "is a FIFO"),
        (["tune", "/dev/zero", "--out", d / "out"], "is a character device"),
        (["front", "export", fifo, "--format", "csv"], "is a FIFO"),
        (["front", "plot", "/dev/null"], "is a character device"),
        (["compare", fifo, fifo], "is a FIFO"),
        (["montecarlo", "--check", fifo], "is a FIFO"),
        (["sweep", "--check", "/dev/zero"], "is a character device"),
        (["demo", "--params", "/dev/zero"], "is a character device"),
    ]
    for argv, msg in cases:
        assert_refused(argv, capsys, d, msg, timeout=120)
    assert not (d / "out").exists()


def test_reader_never_blocks_on_a_fifo(tmp_path):
    """Even past the stat check (a FIFO swapped in), the non-blocking open and fstat refuse it."""
    fifo = tmp_path / "p"
    os.mkfifo(fifo)
    with pytest.raises(files.FileError, match="is a FIFO"):
        files.read_bytes(fifo)
    real = files.check_input
    try:
        files.check_input = lambda p, *a, **k: p  # as if it had been a regular file at stat time
        with pytest.raises(files.FileError, match="is a FIFO"):
            files.read_bytes(fifo)
    finally:
        files.check_input = real


def test_front_given_as_a_directory_is_still_an_input(tmp_path, capsys):
    front = synthetic_front(tmp_path / "front.h5")
    assert_refused(["front", "export", tmp_path, "--format", "csv", "--out", front], capsys, tmp_path, "is the input")


def test_format_sniffing_never_opens_a_fifo(tmp_path):
    from arvcas.experiments.montecarlo import is_montecarlo_file
    from arvcas.experiments.robust import is_robust_file

    import threading

    fifo = tmp_path / "p.h5"
    os.mkfifo(fifo)
    got = []
    t = threading.Thread(target=lambda: got.append((files.hdf5_format(fifo), is_montecarlo_file(fifo),
                                                    is_robust_file(fifo), files.hdf5_format("/dev/zero"))),
                         daemon=True)
    t.start()
    t.join(60)
    assert not t.is_alive(), "sniffing the format of a FIFO blocked"
    assert got == [(None, False, False, None)]
    assert files.hdf5_format(tmp_path / "missing.h5") is None
