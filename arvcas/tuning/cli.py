"""Command-line front ends of the tuning package: ``tune``, ``front export|plot``, ``compare``.

:func:`register` adds them to :data:`arvcas.cli.COMMANDS`. Handlers parse, call one library
function with typed arguments and print; library errors are ValueError/OSError subclasses, which
``arvcas.cli.main`` prints as one line.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

__all__ = ["register"]


# ---- tune -----------------------------------------------------------------------------------------


def _add_tune(p: argparse.ArgumentParser) -> None:
    p.add_argument("study", type=Path, help="study file (TOML), e.g. studies/quick.toml")
    p.add_argument("--out", type=Path, required=True, metavar="DIR",
                   help="output directory (created if its parent exists): DIR/front.h5, or DIR/<controller>/front.h5 "
                        "for a study of several controllers")
    p.add_argument("--resume", action="store_true", help="continue the checkpoint in DIR (bit-identical)")
    p.add_argument("--controller", action="append", default=None, metavar="NAME",
                   help="run only this controller of the study (repeatable)")
    p.add_argument("--engine", choices=("local", "dask"), default=None, help="override the study's engine")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler address (implies --engine dask); without it dask starts a local cluster")
    p.add_argument("--threads", type=int, default=None, metavar="N", help="local engine: threads (default all cores)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="dask local cluster: single-threaded workers (default one per core)")
    p.add_argument("--timeout", type=float, default=None, metavar="S",
                   help="dask: seconds to wait for the scheduler (default: the study's, 10)")


def _run_tune(a: argparse.Namespace) -> int:
    import dataclasses

    from arvcas.tuning.compare import compare_fronts, format_comparison
    from arvcas.tuning.run import run_study
    from arvcas.tuning.study import ENGINES, StudyError, load_study

    study = load_study(a.study)
    eng = study.engine
    if a.scheduler is not None:
        if a.engine == "local":
            raise StudyError("--scheduler: only with --engine dask")
        eng = dataclasses.replace(eng, name="dask", scheduler=a.scheduler)
    if a.engine is not None and a.engine != eng.name:
        eng = dataclasses.replace(eng, name=a.engine, scheduler=None if a.engine == "local" else eng.scheduler)
    for opt, field in (("threads", "threads"), ("workers", "workers"), ("timeout", "timeout_s")):
        v = getattr(a, opt)
        if v is not None:
            if v <= 0 or (opt != "timeout" and int(v) != v):
                raise StudyError(f"--{opt}: must be a positive {'number' if opt == 'timeout' else 'integer'}, got {v}")
            eng = dataclasses.replace(eng, **{field: v})
    assert eng.name in ENGINES
    study = study.with_engine(eng)

    def say(msg: str) -> None:
        print(msg, flush=True)

    outs = run_study(study, a.out, controllers=tuple(a.controller) if a.controller else None, resume=a.resume,
                     say=say, study_file=str(a.study))
    for o in outs:
        print(f"{o.controller}: {o.status} after {o.n_gen} generations, {o.n_eval} runs, {o.front_size} on the front, "
              f"HV {o.hv:.6g}; {o.path}")
    done = [o for o in outs if o.status == "finished"]
    if len(done) == 2:
        print(format_comparison(compare_fronts(done[0].path, done[1].path)))
    if any(o.status == "interrupted" for o in outs):
        return 130
    return 0


# ---- front ---------------------------------------------------------------------------------------


def _add_front(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    e = sub.add_parser("export", help="the front as CSV or JSON (stdout, or --out FILE)")
    e.add_argument("file", type=Path, help="front.h5 (or a study output directory)")
    e.add_argument("--format", required=True, choices=("csv", "json"))
    e.add_argument("--out", type=Path, default=None, metavar="FILE")
    pl = sub.add_parser("plot", help="plot the front, Table 2 on the same draws and the knee point (PNG)")
    pl.add_argument("file", type=Path, help="front.h5 (or a study output directory)")
    pl.add_argument("--out", type=Path, default=None, metavar="PNG", help="default: next to FILE, front.png")
    pl.add_argument("--paper", action="store_true", help="also mark the paper's Table 3 points (their simulator)")


def _write_text(path: Path, text: str) -> None:
    from arvcas.tuning.checkpoint import CheckpointError

    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise CheckpointError(f"--out {path}: directory {parent} does not exist")
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _run_front(a: argparse.Namespace) -> int:
    from arvcas.tuning.front import export_front, plot_front, read_front, resolve_front_path

    if a.action == "export":
        text = export_front(a.file, a.format)
        if a.out is None:
            sys.stdout.write(text)
        else:
            _write_text(a.out, text)
            print(f"wrote {a.out}")
        return 0
    fr = read_front(a.file)
    out = a.out if a.out is not None else resolve_front_path(a.file).with_suffix(".png")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise ValueError(f"--out {out}: directory {parent} does not exist")
    fig = plot_front(fr, paper=a.paper)
    fig.savefig(out, dpi=150)
    k = fr.knee()
    print(f"{fr.controller}: {fr.size} on the front, HV {fr.hv:.6g}; knee: member {k} "
          f"(f_chat {fr.F[k, 0]:.4g}, f_rmse {fr.F[k, 1]:.4g}); wrote {out}")
    return 0


# ---- compare -------------------------------------------------------------------------------------


def _add_compare(p: argparse.ArgumentParser) -> None:
    p.add_argument("a", type=Path, metavar="DIR_A", help="study output directory or front.h5")
    p.add_argument("b", type=Path, metavar="DIR_B", help="study output directory or front.h5")
    p.add_argument("--ref", default=None, metavar="F_CHAT,F_RMSE",
                   help="common reference point (default: componentwise max of the two studies' points)")
    p.add_argument("--plot", type=Path, default=None, metavar="PNG", help="both fronts in one figure")
    p.add_argument("--paper", action="store_true", help="with --plot: also mark the paper's Table 3 points")


def _run_compare(a: argparse.Namespace) -> int:
    from arvcas.tuning.compare import compare_fronts, format_comparison
    from arvcas.tuning.front import plot_fronts, read_front

    ref = None
    if a.ref is not None:
        try:
            ref = [float(x) for x in a.ref.split(",")]
        except ValueError:
            ref = None
        if ref is None or len(ref) != 2:
            raise ValueError(f"--ref: expected two numbers 'f_chat,f_rmse', got {a.ref!r}")
    fa, fb = read_front(a.a), read_front(a.b)
    if a.plot is not None:
        parent = a.plot.parent if str(a.plot.parent) else Path(".")
        if not parent.is_dir():
            raise ValueError(f"--plot {a.plot}: directory {parent} does not exist")
    c = compare_fronts(fa, fb, ref)
    print(format_comparison(c))
    if a.plot is not None:
        fig = plot_fronts([fa, fb], labels=list(c.labels), paper=a.paper)
        fig.axes[0].set_title(f"{c.labels[0]} vs {c.labels[1]}: HV {c.hv[0]:.4g} vs {c.hv[1]:.4g} "
                              f"(ref {c.reference_point[0]:g}, {c.reference_point[1]:g})", fontsize=9)
        fig.savefig(a.plot, dpi=150)
        print(f"wrote {a.plot}")
    return 0


def register(commands: dict) -> None:
    """Add ``tune``, ``front`` and ``compare`` to the CLI's command table."""
    from arvcas.cli import Command

    commands["tune"] = Command("NSGA-II on the CHAT/RMSE front from a study file (resumable, local or Dask)",
                               _add_tune, _run_tune)
    commands["front"] = Command("export (csv, json) or plot a tuning front", _add_front, _run_front)
    commands["compare"] = Command("hypervolumes of two fronts against one reference point, and who dominates where",
                                  _add_compare, _run_compare)
