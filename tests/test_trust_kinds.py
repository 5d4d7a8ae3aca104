"""One output policy for every kind of arvcas file: a checkpoint, a front, a Monte Carlo file, an export
is never replaced by another command (or another library writer) without --force; --force never writes
through a symbolic link out of the output directory; the Python API decides by the manifest, never by a
claim inside the file (no zip is opened); temporaries of every writer, files and directories, are
cleaned once their process is gone."""

from __future__ import annotations

import os
import subprocess
import zipfile

import h5py
import pytest

from arvcas.build import export, fmu
from arvcas.util import files
from arvcas.io.results import ResultsError, atomic_write

from trust_helpers import assert_refused, run, snapshot, synthetic_front


def _dead_pid() -> int:
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


def _montecarlo_like(path):
    """An HDF5 file with arvcas's Monte Carlo format attribute (what the writer checks)."""
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "arvcas-montecarlo"
    return path


def test_another_commands_file_is_not_replaced(tmp_path, capsys):
    d = tmp_path
    front = synthetic_front(d / "front.h5")
    mc = _montecarlo_like(d / "mc.h5")
    cases = [
        (["simulate", "--controller", "proposed", "--out", front], "another kind (arvcas.tuning.front)"),
        (["simulate", "--controller", "proposed", "--out", mc], "another kind (arvcas-montecarlo)"),
        (["montecarlo", "--controller", "agsta", "--runs", "2", "--out", front], "another kind (arvcas.tuning"),
    ]
    for argv, msg in cases:
        assert_refused(argv, capsys, d, msg)
    # the library writers apply the same policy (a result written over a checkpoint from Python)
    before = snapshot(d)
    with pytest.raises(ResultsError, match=r"another kind \(arvcas.tuning.front\); refusing to replace it with "
                                           r"arvcas-result"):
        atomic_write(front, lambda t: t.write_bytes(b"x"), "arvcas-result")
    assert snapshot(d) == before
    # a text file arvcas wrote as an export is not replaced by another writer's text either
    (d / "x").mkdir()
    files.write_text(d / "x" / "README.md", "export\n", kind=export.KIND)
    with pytest.raises(files.FileError, match=r"another kind \(export-c\)"):
        files.write_text(d / "x" / "README.md", "table\n")
    # --force replaces it (the user's decision), by the same writer
    rc, err = run(["simulate", "--controller", "proposed", "--out", mc, "--force"], capsys)
    assert rc == 0, err
    assert files.kind_of(mc) == "arvcas-result"


def test_force_never_writes_through_a_link_out_of_the_directory(tmp_path, capsys):
    out, elsewhere = tmp_path / "out", tmp_path / "user_project"
    out.mkdir()
    elsewhere.mkdir()
    (elsewhere / "CMakeLists.txt").write_text("# the user's own build\n")
    (out / "consumer").symlink_to(elsewhere)
    before = snapshot(tmp_path)
    for force in ([], ["--force"]):
        assert_refused(["export-c", out, *force], capsys, tmp_path, "consumer: is a symbolic link")
    with pytest.raises(export.ExportError, match="consumer: is a symbolic link"):  # the Python API too
        export.export_c(out, force=True)
    assert snapshot(tmp_path) == before


def test_export_fmu_decides_by_manifest_not_by_the_files_claim(tmp_path):
    claim = tmp_path / "claims.fmu"
    with zipfile.ZipFile(claim, "w") as zf:
        zf.writestr("modelDescription.xml", '<fmiModelDescription fmiVersion="2.0" generationTool="arvcas 0.1.0"/>')
    # a zip bomb's worth of declared size: never opened, so never unpacked
    bomb = tmp_path / "bomb.fmu"
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("modelDescription.xml", b"<" * (64 << 20))
    before = snapshot(tmp_path)
    for p in (claim, bomb):
        with pytest.raises(fmu.FMUError, match="is not an FMU written by arvcas"):
            fmu.export_fmu(p)
    # a result file arvcas wrote is not an FMU either
    files.write_text(tmp_path / "r.fmu", "x", kind="arvcas-result")
    with pytest.raises(fmu.FMUError, match=r"another kind \(arvcas-result\)"):
        fmu.export_fmu(tmp_path / "r.fmu")
    assert {k: v for k, v in snapshot(tmp_path).items() if k in before} == before


def test_stale_temporaries_of_every_writer_are_removed(tmp_path, monkeypatch):
    dead = _dead_pid()
    stale_dir = tmp_path / f".x.fmu{files.TMP_MARK}{dead}-abc"  # an FMU export killed while compiling
    stale_dir.mkdir()
    (stale_dir / "sources").mkdir()
    (stale_dir / "sources" / "model.c").write_text("int x;\n")
    stale_file = tmp_path / f".r.h5{files.TMP_MARK}{dead}-xyz"
    stale_file.write_bytes(b"half")
    live = tmp_path / f".y.png{files.TMP_MARK}{os.getppid()}-abc"  # a running process's: kept
    live.write_bytes(b"being written")
    files.write_text(tmp_path / "notes.md", "any writer\n")  # the library writer, no command around it
    assert not stale_dir.exists() and not stale_file.exists() and live.exists()
    # private directories (a build beside a read-only cache, libraries shipped to a worker) live in the
    # system's temporary directory and are removed there once their process is gone
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    old = tmp_path / f"arvcas-private-{dead}-build-abc"
    old.mkdir()
    (old / "f.so").write_bytes(b"\x7fELF")
    mine = files.private_dir("build")
    try:
        assert mine.parent == tmp_path and not old.exists() and mine.is_dir()
    finally:
        files.release_temp(mine)
