"""Command-line handlers of the tuning package: ``tune``, ``front export``, ``front plot``, ``compare`` of fronts.

The commands are declared in the table of :mod:`arvcas.cli` (which applies the input and output
policies before calling a handler). Handlers call one library function with typed arguments and
print; library errors are ValueError/OSError subclasses, which ``arvcas.cli.main`` prints as one line.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["add_tune", "check_tune", "run_tune", "add_front_export", "run_front_export", "add_front_plot",
           "run_front_plot", "front_plot_outputs", "add_compare", "run_compare", "add_front_restamp",
           "run_front_restamp"]


# ---- tune -----------------------------------------------------------------------------------------


def add_tune(p: argparse.ArgumentParser) -> None:
    from arvcas.io.cliargs import count_arg, seconds_arg

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
    p.add_argument("--threads", type=count_arg(1, 1024, "--threads"), default=None, metavar="N",
                   help="local engine: threads (default all cores)")
    p.add_argument("--workers", type=count_arg(1, 1024, "--workers"), default=None, metavar="N",
                   help="dask local cluster: single-threaded workers (default one per core)")
    p.add_argument("--timeout", type=seconds_arg, default=None, metavar="S",
                   help="dask: seconds to wait for the scheduler, and for a worker when all are lost "
                        "(default: the study's, 10)")
    p.add_argument("--allow-model-change", action="store_true",
                   help="with --resume: continue even if the model code or parameters changed since the "
                        "checkpoint was written (the checkpoint records it)")


def check_tune(a: argparse.Namespace) -> None:
    """Options that do not apply (the study's engine is checked in :func:`run_tune`, once it is read)."""
    from arvcas.io.cliargs import refuse

    if not a.resume:
        refuse(a, ("allow_model_change",), "only with --resume")
    if a.engine == "local":
        refuse(a, ("scheduler", "workers", "timeout"), "only with --engine dask")
    if a.scheduler is not None:
        refuse(a, ("threads",), "only with the local engine (--scheduler was given)")
        refuse(a, ("workers",), "a remote scheduler has its own workers (--workers is for a local cluster)")


def run_tune(a: argparse.Namespace) -> int:
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
    for opt, field, engine in (("threads", "threads", "local"), ("workers", "workers", "dask"),
                               ("timeout", "timeout_s", "dask")):
        v = getattr(a, opt)
        if v is not None:
            if eng.name != engine:
                raise StudyError(f"--{opt}: only with the {engine} engine (this run uses {eng.name})")
            eng = dataclasses.replace(eng, **{field: v})
    assert eng.name in ENGINES
    study = study.with_engine(eng)

    def say(msg: str) -> None:
        print(msg, flush=True)

    outs = run_study(study, a.out, controllers=tuple(a.controller) if a.controller else None, resume=a.resume,
                     say=say, study_file=str(a.study), allow_model_change=a.allow_model_change)
    for o in outs:
        print(f"{o.controller}: {o.status} after {o.n_gen} generations, {o.n_eval} runs, {o.front_size} on the front, "
              f"HV {o.hv:.6g}; {o.path}")
    done = [o for o in outs if o.status == "finished"]
    if len(done) >= 2:
        print(format_comparison(compare_fronts(*[o.path for o in done])))
    if any(o.status == "interrupted" for o in outs):
        return 130
    return 0


# ---- front ---------------------------------------------------------------------------------------


def add_front_export(e: argparse.ArgumentParser) -> None:
    e.add_argument("file", type=Path, help="front.h5 (or a study output directory)")
    e.add_argument("--format", required=True, choices=("csv", "json", "mat"),
                   help="csv, json (text), or mat (a MATLAB file: needs --out FILE.mat)")
    e.add_argument("--out", type=Path, default=None, metavar="FILE", help="default: standard output")


def add_front_plot(pl: argparse.ArgumentParser) -> None:
    from arvcas.io.cliargs import add_figure_format

    pl.add_argument("file", type=Path, help="front.h5 (or a study output directory)")
    pl.add_argument("--out", type=Path, default=None, metavar="FIGURE",
                    help="a .png, .pdf or .svg file (default: next to FILE, front.png or front.<--format>)")
    pl.add_argument("--paper", action="store_true",
                    help="Haidou-1: also mark the paper's Table 3 points (their simulator)")
    add_figure_format(pl)


def add_front_restamp(p: argparse.ArgumentParser) -> None:
    from arvcas.io.cliargs import count_arg

    p.add_argument("fronts", type=Path, nargs="+", metavar="FRONT",
                   help="front.h5 files or study output directories (every front in them)")
    p.add_argument("--check", action="store_true",
                   help="replay and report only; write nothing (exit 1 if a front does not replay bit for bit or "
                        "its run digest is not today's)")
    p.add_argument("--threads", type=count_arg(1, 1024, "--threads"), default=None, metavar="N",
                   help="threads of the replay (default 1)")


def run_front_restamp(a: argparse.Namespace) -> int:
    """Replay every member and the default gains of each front on today's code; where every number is
    reproduced bit for bit, record today's run digest (docs/provenance.md)."""
    from arvcas.tuning import checkpoint as ck
    from arvcas.tuning.front import front_paths, replay_all, restamp

    paths = [f for p in a.fronts for f in front_paths(p)]
    bad = 0
    for path in paths:
        c = ck.read_checkpoint(path)
        try:
            r = replay_all(path, "all", a.threads) if a.check else restamp(path, a.threads)
        except ck.CheckpointError as e:
            print(f"FAILED {e}")
            bad += 1
            continue
        if a.check:
            ok = r.bitwise and c.run_digest == r.run_digest and c.system_variant == r.system_variant
            bad += not ok
            why = "" if ok or not r.bitwise else "; its run digest is not today's (re-stamp it)"
            print(f"{'ok' if ok else 'FAILED'} {r.describe()}{why}")
        else:
            print(f"{'unchanged' if c.run_digest == r.run_digest else 're-stamped'} {r.describe()}")
    return 1 if bad else 0


def check_front_export(a: argparse.Namespace) -> None:
    if a.format == "mat" and (a.out is None or a.out.suffix != ".mat"):
        raise ValueError("front export --format mat: needs --out FILE.mat (a binary file, not standard output)")


def run_front_export(a: argparse.Namespace) -> int:
    from arvcas.util import files
    from arvcas.tuning.checkpoint import CheckpointError
    from arvcas.tuning.front import export_front

    if a.out is not None:
        files.target(a.out, f"--out {a.out}", CheckpointError)
    if a.format == "mat":
        from arvcas.io.matfile import write_front_mat
        from arvcas.tuning.front import read_front

        print(f"wrote {write_front_mat(read_front(a.file), a.out)}")
        return 0
    text = export_front(a.file, a.format)
    if a.out is None:
        sys.stdout.write(text)
    else:
        files.write_text(a.out, text, CheckpointError)
        print(f"wrote {a.out}")
    return 0


def front_plot_outputs(a: argparse.Namespace) -> list:
    from arvcas.io.cliargs import figure_file
    from arvcas.tuning.front import resolve_front_path

    out = a.out if a.out is not None else resolve_front_path(a.file).with_suffix(f".{a.format or 'png'}")
    figure_file(out, a.format, f"--out {out}")
    return [("--out", out)]


def run_front_plot(a: argparse.Namespace) -> int:
    from arvcas.io.cliargs import figure_file
    from arvcas.util import files
    from arvcas.io import style
    from arvcas.tuning.front import plot_front, read_front

    fr = read_front(a.file)
    out = front_plot_outputs(a)[0][1]
    files.target(out, f"--out {out}")
    fig = plot_front(fr, paper=a.paper)
    style.write_figure(out, fig, figure_file(out, a.format, f"--out {out}"))
    k = fr.knee()
    print(f"{fr.controller}: {fr.size} on the front, HV {fr.hv:.6g}; knee: member {k} "
          f"({fr.describe(k)}); wrote {out}")
    return 0


# ---- compare -------------------------------------------------------------------------------------


def add_compare(p: argparse.ArgumentParser) -> None:
    from arvcas.io.cliargs import add_figure_format

    p.add_argument("fronts", type=Path, nargs="+", metavar="DIR",
                   help="two or more study output directories or front.h5 files (or two Monte Carlo or robust-front "
                        "files)")
    p.add_argument("--ref", default=None, metavar="F_CHAT,F_RMSE",
                   help="common reference point (default: componentwise max of the studies' points)")
    p.add_argument("--plot", type=Path, default=None, metavar="FIGURE",
                   help="the fronts in one figure (.png, .pdf or .svg)")
    add_figure_format(p, "--plot")
    p.add_argument("--paper", action="store_true",
                   help="with --plot, Haidou-1 fronts: also mark the paper's Table 3 points")
    p.add_argument("--allow-model-change", action="store_true",
                   help="compare fronts computed with different model code or parameters")


def run_compare(a: argparse.Namespace) -> int:
    """Two or more fronts (``compare`` on Monte Carlo files is :func:`arvcas.experiments.cli.run_compare`)."""
    from arvcas.io.cliargs import figure_file
    from arvcas.util import files
    from arvcas.io import style
    from arvcas.tuning.compare import compare_fronts, format_comparison
    from arvcas.tuning.front import check_same_model, plot_fronts, read_front

    ref = None
    if a.ref is not None:
        try:
            ref = [float(x) for x in a.ref.split(",")]
        except ValueError:
            ref = None
        if ref is None:
            raise ValueError(f"--ref: expected numbers separated by commas, one per objective ('f_chat,f_rmse'), "
                             f"got {a.ref!r}")
    frs = [read_front(p) for p in a.fronts]
    changed = sorted({w for f in frs[1:] for w in [check_same_model(frs[0].path, f.path, a.allow_model_change)] if w})
    if changed:
        print(f"note: the {'two ' if len(frs) == 2 else ''}fronts were computed with different models ({'; '.join(changed)}); compared as allowed by "
              f"--allow-model-change")
    fmt = None
    if a.plot is not None:
        files.target(a.plot, f"--plot {a.plot}")
        fmt = figure_file(a.plot, a.format, f"--plot {a.plot}")
    c = compare_fronts(*frs, ref=ref)
    print(format_comparison(c))
    if a.plot is not None:
        fig = plot_fronts(frs, labels=list(c.labels), paper=a.paper)
        hv = " vs ".join(f"{h:.4g}" for h in c.hv)
        fig.axes[0].set_title(f"{' vs '.join(c.labels)}: HV {hv} (ref {c.reference_point[0]:g}, "
                              f"{c.reference_point[1]:g})", fontsize=7)
        style.write_figure(a.plot, fig, fmt)
        print(f"wrote {a.plot}")
    return 0
