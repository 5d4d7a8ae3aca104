"""Output policy: no output is an input or another output, a file arvcas did not write is never replaced
without --force, every write is atomic (also on SIGTERM), stale temporary files are cleaned."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from arvcas.util import files
from arvcas.io.results import read_result

from trust_helpers import assert_refused, run, snapshot, synthetic_front


@pytest.fixture()
def front(tmp_path):
    return synthetic_front(tmp_path / "front.h5")


def _foreign(p, text="my notes\n"):
    p.write_text(text)
    return p


def test_output_refusals(tmp_path, front, capsys):
    d = tmp_path
    notes = _foreign(d / "notes.txt")
    os.link(front, d / "hard.csv")
    os.symlink(front, d / "soft.csv")
    (d / "md").mkdir()
    _foreign(d / "md" / "table3.md")
    (d / "bench").mkdir()
    _foreign(d / "bench" / "bench.md")
    os.mkfifo(d / "pipe.png")
    cases = [
        (["front", "export", front, "--format", "csv", "--out", front], "is the input file"),
        (["front", "export", front, "--format", "csv", "--out", d / "hard.csv"], "is the input file"),
        (["front", "export", front, "--format", "csv", "--out", d / "soft.csv"], "is the input file"),
        (["front", "export", d, "--format", "csv", "--out", front, "--force"], "is the input file"),
        (["front", "export", front, "--format", "json", "--out", notes], "was not written by arvcas"),
        (["front", "plot", front, "--out", d / "pipe.png"], "is a FIFO"),
        (["simulate", "--controller", "proposed", "--out", notes], "was not written by arvcas"),
        (["simulate", "--controller", "proposed", "--out", d / "md"], "is a directory"),
        (["montecarlo", "--controller", "agsta", "--runs", "2", "--out", d / "X.md"], "is also the output --out"),
        (["paper", "--out", d / "md"], "was not written by arvcas"),
        (["bench", "--quick", "--out", d / "bench"], "was not written by arvcas"),
        (["compare", front, front, "--plot", front], "is the input front"),
        (["simulate", "--controller", "agsta", "--config", notes, "--out", notes, "--force"], "is the input --config"),
    ]
    for argv, msg in cases:
        assert_refused(argv, capsys, d, msg)


def test_force_replaces_a_foreign_file(tmp_path, capsys):
    notes = _foreign(tmp_path / "notes.txt")
    rc, err = run(["simulate", "--controller", "proposed", "--out", notes, "--force"], capsys)
    assert rc == 0, err
    assert read_result(notes).controller == "proposed"
    assert not [p for p in os.listdir(tmp_path) if files.TMP_MARK in p]


def test_own_text_outputs_are_recognised_until_edited(tmp_path, front, capsys):
    out = tmp_path / "f.csv"
    argv = ["front", "export", front, "--format", "csv", "--out", out]
    assert run(argv, capsys)[0] == 0
    first = out.read_bytes()
    assert run(argv, capsys)[0] == 0  # arvcas's own file (manifest): replaced without --force
    assert out.read_bytes() == first and files.written_by_arvcas(out)
    out.write_text(out.read_text() + "my edit\n")  # now the user's
    assert not files.written_by_arvcas(out)
    assert_refused(argv, capsys, tmp_path, "was changed since arvcas wrote it")
    (tmp_path / files.MANIFEST).write_text("{not json")
    assert_refused(["front", "export", front, "--format", "csv", "--out", tmp_path / "g.csv"], capsys, tmp_path,
                   "not an arvcas manifest")


def test_library_writer_refuses_a_foreign_file(tmp_path):
    p = _foreign(tmp_path / "x.md")
    before = snapshot(tmp_path)
    with pytest.raises(files.FileError, match="was not written by arvcas"):
        files.write_text(p, "new")
    assert snapshot(tmp_path) == before


def test_sigterm_during_a_write_keeps_the_previous_file(tmp_path, front, capsys, monkeypatch):
    """`front plot` killed by SIGTERM while the PNG is being written: the previous PNG stays, no temp file."""
    from matplotlib.figure import Figure

    png = tmp_path / "front.png"
    assert run(["front", "plot", front], capsys)[0] == 0
    before = snapshot(tmp_path)
    real = Figure.savefig

    def killed_while_saving(self, fname, *a, **k):
        with open(fname, "wb") as fh:
            fh.write(b"\x89PNG half")
        os.kill(os.getpid(), signal.SIGTERM)
        return real(self, fname, *a, **k)  # not reached

    monkeypatch.setattr(Figure, "savefig", killed_while_saving)
    from arvcas import cli  # cli.main installs the SIGTERM handler (main thread)

    code = cli.main(["front", "plot", str(front)])
    err = capsys.readouterr().err
    assert code == 128 + signal.SIGTERM and "terminated (SIGTERM)" in err
    assert snapshot(tmp_path) == before and png.stat().st_size > 0


class _Hostile:
    """An argument CasADi's overload resolution asks for ``tocsc`` (``casadi.casadi.DM_from_csc``): the signal
    comes then, so its handler raises inside a converter whose exceptions SWIG discards."""

    sent = False

    def __getattr__(self, name):
        if name == "tocsc" and not self.sent:  # once: CasADi tries the converter for more than one overload
            self.sent = True
            os.kill(os.getpid(), signal.SIGTERM)
        raise AttributeError(name)


@pytest.mark.parametrize("where", ["before the write", "in a command that writes nothing"])
def test_a_signal_casadi_swallows_still_ends_the_command(tmp_path, front, capsys, monkeypatch, where):
    """SIGTERM while CasADi resolves an overload (as during a run's graph construction): CasADi drops the
    Terminated the handler raised (the call fails with its own NotImplementedError, or succeeds through another
    overload); the command still ends with 143 in one line, and the previous file stays."""
    import casadi as ca
    from matplotlib.figure import Figure

    from arvcas import cli

    assert run(["front", "plot", front], capsys)[0] == 0
    before = snapshot(tmp_path)
    swallowed = []

    def signal_inside_casadi():
        try:
            ca.mtimes(_Hostile(), ca.SX.sym("x"))
        except NotImplementedError:  # CasADi's own error, not the Terminated: the signal's exception is gone
            swallowed.append(True)

    if where == "before the write":
        real = Figure.savefig

        def savefig(self, fname, *a, **k):
            signal_inside_casadi()
            return real(self, fname, *a, **k)

        monkeypatch.setattr(Figure, "savefig", savefig)
        argv = ["front", "plot", str(front)]
    else:
        from arvcas.tuning import front as front_mod

        real_export = front_mod.export_front

        def export_front(*a, **k):
            signal_inside_casadi()
            return real_export(*a, **k)

        monkeypatch.setattr(front_mod, "export_front", export_front)
        argv = ["front", "export", str(front), "--format", "csv"]  # to standard output
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert swallowed == [True], "CasADi no longer discards an exception raised in its converters"
    assert code == 128 + signal.SIGTERM and err.strip().splitlines()[-1] == "arvcas: terminated (SIGTERM)", err
    assert snapshot(tmp_path) == before
    monkeypatch.undo()
    # the next command starts clean, in this thread or another (cli.main forgets the signal when it returns)
    assert cli.main(["front", "export", str(front), "--format", "json"]) == 0
    assert run(["front", "export", front, "--format", "json"], capsys)[0] == 0


def test_sighup_in_a_subprocess_leaves_no_temp_file(tmp_path):
    code = (
        "import os, signal, sys\n"
        "from pathlib import Path\n"
        "from arvcas.util import files\n"
        "files.install_signal_handlers()\n"
        "def w(p):\n"
        "    p.write_bytes(b'half')\n"
        "    os.kill(os.getpid(), signal.SIGHUP)\n"
        "try:\n"
        "    files.atomic_write(Path(sys.argv[1]), w)\n"
        "except files.Terminated:\n"
        "    sys.exit(3)\n"
    )
    target = tmp_path / "out.md"
    files.write_text(target, "previous\n")
    before = snapshot(tmp_path)
    from test_tuning_run import default_signals

    r = subprocess.run([sys.executable, "-c", code, str(target)], timeout=120, preexec_fn=default_signals)
    assert r.returncode == 3
    assert snapshot(tmp_path) == before


def test_stale_temporaries_of_killed_runs_are_removed(tmp_path, front, capsys):
    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = tmp_path / f".front.png{files.TMP_MARK}{dead.pid}-abc"
    stale.write_bytes(b"half a figure")
    live = tmp_path / f".front.png{files.TMP_MARK}{os.getppid()}-abc"  # a running process's: kept
    live.write_bytes(b"being written")
    assert run(["front", "plot", front], capsys)[0] == 0
    assert not stale.exists() and live.exists()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_tune_ended_by_sigterm_or_sighup_keeps_its_checkpoint(tmp_path, sig):
    from arvcas.tuning import checkpoint as ck

    from test_tuning_run import _tune_process, _wait_for
    from test_tuning_study import write_tiny

    study = write_tiny(tmp_path / "tiny.toml", generations=50)
    out = tmp_path / "out"
    p = _tune_process(study, out)
    _wait_for(p, "gen 1/")
    p.send_signal(sig)
    _stdout, stderr = p.communicate(timeout=120)
    assert p.returncode == 128 + sig, stderr
    assert f"terminated ({signal.Signals(sig).name})" in stderr and "Traceback" not in stderr, stderr
    c = ck.read_checkpoint(out / "front.h5")
    assert 1 <= c.n_gen < 50
    assert not [n for n in os.listdir(out) if files.TMP_MARK in n] and not (out / ck.StudyLock.NAME).exists()
