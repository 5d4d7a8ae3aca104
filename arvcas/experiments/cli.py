"""Command-line handlers of :mod:`arvcas.experiments`: ``simulate``, ``paper``, ``knees``, ``sweep``,
``montecarlo``, ``front robust``, ``front explore`` and ``compare`` (fronts, Monte Carlo files or robust fronts).

The commands are declared in the table of :mod:`arvcas.cli`, which applies the input and output
policies before calling a handler; ``check_*`` refuse options that do not apply and requests too large,
``*_outputs`` name the files a command will write. Each ``run_*`` calls a library function with typed
arguments; errors are ValueError/OSError (one line via arvcas.cli).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from arvcas.io.cliargs import (RESULT_FORMATS, add_figure_format, add_model_args, add_system_arg, model_options,
                               output_kinds, refuse, seed_arg)

__all__ = ["add_sweep", "check_sweep", "run_sweep", "sweep_outputs", "add_montecarlo", "check_montecarlo",
           "run_montecarlo", "montecarlo_outputs", "add_robust", "check_robust", "run_robust", "robust_outputs",
           "add_compare", "check_compare", "run_compare", "compare_outputs", "add_explore", "check_explore", "run_explore", "explore_outputs",
           "add_simulate", "check_simulate", "run_simulate", "add_paper", "run_paper", "paper_outputs", "add_knees",
           "run_knees", "knees_outputs", "MAX_RUNS", "MAX_SEEDS"]

MAX_RUNS = 1_000_000  # Monte Carlo draws per study (or per front member)
MAX_SEEDS = 10_000  # noise seeds of a sweep
_MAX_H = 1_000  # sampling periods of a sweep


def _floats(text: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got '{text}'") from None


def _seeds(text: str) -> list[int]:
    """Seeds ``S1,S2,...`` or ``A..B`` (inclusive): each 0 <= s < 2**63, at most MAX_SEEDS (checked before
    the list is built)."""
    from arvcas.io.cliargs import MAX_SEED

    try:
        if ".." in text:  # a range A..B (inclusive)
            a, b = (int(x) for x in text.split("..", 1))
            lo, hi, n = a, b, b - a + 1
        else:
            vals = [int(x) for x in text.split(",") if x.strip()]
            lo, hi, n = (min(vals), max(vals), len(vals)) if vals else (0, 0, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers or A..B, got '{text}'") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"'{text}': no seeds")
    if n > MAX_SEEDS:
        raise argparse.ArgumentTypeError(f"'{text}': {n} seeds, more than {MAX_SEEDS}")
    if lo < 0 or hi >= MAX_SEED:
        raise argparse.ArgumentTypeError(f"'{text}': seeds out of range (allowed: 0 <= seed < 2**63)")
    return list(range(lo, hi + 1)) if ".." in text else vals


def _runs(text: str) -> int:
    from arvcas.io.cliargs import count_arg

    return count_arg(1, MAX_RUNS, "--runs")(text)


def _seed(text: str) -> int:
    from arvcas.io.cliargs import seed_arg

    return seed_arg(text)


def _names(text: str) -> list[str]:
    return [x.strip() for x in text.split(",") if x.strip()]


def _say(msg: str) -> None:
    print(msg, flush=True)


# ---- sweep -------------------------------------------------------------------------------------


def add_sweep(p: argparse.ArgumentParser) -> None:
    p.add_argument("--h", type=_floats, default=None, metavar="H1,H2,...",
                   help="controller sampling periods in s (the plant's RK4 step: the scenario's where it divides h, "
                        "else the largest step below it that does)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR", help="writes DIR/sweep.h5, sweep.md, sweep.png")
    p.add_argument("--controllers", type=_names, default=None, metavar="A,B,...",
                   help="default: proposed, traditional, implicit, agsta")
    p.add_argument("--seeds", type=_seeds, default=None, metavar="S1,S2|A..B", help="noise seeds (default 0)")
    p.add_argument("--noise-scale", type=float, default=None, metavar="X",
                   help="multiply the sensor noise by X (0: perfect measurements, the EKF unchanged; default 1)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE", help="scenario file (default: packaged)")
    add_system_arg(p)
    p.add_argument("--check", type=Path, default=None, metavar="FILE.h5",
                   help="re-run a stored sweep from its file alone and compare bit for bit (no other option)")
    _add_format(p)


def _add_format(p: argparse.ArgumentParser) -> None:
    from arvcas.io.cliargs import add_figure_format

    add_figure_format(p)


def check_sweep(a: argparse.Namespace) -> None:
    from arvcas.io.cliargs import check_memory, refuse

    if a.check is not None:
        refuse(a, ("h", "out", "controllers", "seeds", "noise_scale", "config", "params", "force", "format"),
               "--check FILE re-runs the file's own configuration: give no other option")
        return
    if a.h is None or a.out is None:
        raise ValueError("sweep: --h H1,H2,... and --out DIR are required (or --check FILE.h5)")
    if not 1 <= len(a.h) <= _MAX_H:
        raise ValueError(f"--h: {len(a.h)} sampling periods (allowed: 1..{_MAX_H})")
    if a.noise_scale is not None and not (a.noise_scale >= 0 and a.noise_scale < float("inf")):
        raise ValueError(f"--noise-scale: must be a finite number >= 0, got {a.noise_scale}")
    from arvcas.experiments.sweep import CONTROLLERS

    n_runs = len(a.h) * len(a.controllers or CONTROLLERS) * len(a.seeds or [0])
    # each run keeps its k1 series: (duration / h + 1) x 6 float64; bounded by the smallest h
    from arvcas.sim.scenario import load_scenario

    cfg = load_scenario(a.config)
    h_min = min((h for h in a.h if h > 0), default=cfg.time_h)
    check_memory("sweep", n_runs * (cfg.time_duration / h_min + 1) * 6 * 8 * 2)


def sweep_outputs(a: argparse.Namespace) -> list:
    from arvcas.experiments.sweep import FORMAT

    return [] if a.out is None else [(f"--out {a.out}", a.out / f"sweep.{e}", FORMAT if e == "h5" else None)
                                     for e in ("h5", "md", a.format or "png")]


def _report_check(path, diff: list[str], compared: str) -> int:
    """Print the outcome of re-running the study in ``path`` (``diff``: the fields that differ); exit code."""
    if diff:
        print(f"{path}: NOT reproduced: {', '.join(diff)} differ")
        return 1
    print(f"{path}: reproduced bit for bit ({compared})")
    return 0


def run_sweep(a: argparse.Namespace) -> int:
    from arvcas.sim import scenario
    from arvcas.system.params import load
    from arvcas.experiments import _io
    from arvcas.experiments.sweep import CONTROLLERS, reproduce_sweep, run_sweep, sweep_markdown, write_sweep_dir

    if a.check is not None:
        _say(f"re-running {a.check} ...")
        _new, diff = reproduce_sweep(a.check)
        return _report_check(a.check, diff, "chat, rmse, ok, t_fail, zigzag measures, k1 series")
    _io.prepare_dir(a.out, f"--out {a.out}")
    params = load(a.system)
    cfg = scenario.load_scenario(a.config if a.config is not None else params.default("scenario"))
    sw = run_sweep(a.h, a.controllers or CONTROLLERS, a.seeds or [0], cfg=cfg, system=params,
                   noise_scale=1.0 if a.noise_scale is None else a.noise_scale, progress=_say)
    files = write_sweep_dir(sw, a.out, a.format or "png")
    print(sweep_markdown(sw).split("\n## ", 1)[0])
    for p in files.values():
        print(f"wrote {p}")
    return 0


# ---- montecarlo --------------------------------------------------------------------------------


def add_montecarlo(p: argparse.ArgumentParser) -> None:
    p.add_argument("--controller", default=None, help="proposed, agsta, traditional or implicit")
    p.add_argument("--runs", type=_runs, default=None, metavar="N", help=f"number of draws (1..{MAX_RUNS})")
    p.add_argument("--out", type=Path, default=None, metavar="FILE.h5",
                   help="result file; a summary FILE.md is written next to it")
    p.add_argument("--seed", type=_seed, default=None, help="master seed of the draws (default 0)")
    p.add_argument("--spread", type=float, default=None,
                   help="half-width of the nominal-model factors' uniform draw around 1 (default 0.3: +-30 %%)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE", help="scenario file (default: packaged)")
    add_system_arg(p)
    p.add_argument("--from-front", type=Path, default=None, metavar="FRONT",
                   help="use the gains of a tuning front member (with --index)")
    p.add_argument("--index", default=None, help="front member: an integer, or 'knee'")
    p.add_argument("--draws-toml", action="store_true",
                   help="print the --runs draws of --seed as [[evaluation.draws]] tables for a tuning study file "
                        "(optimise the mean over K draws) and exit")
    p.add_argument("--check", type=Path, default=None, metavar="FILE.h5",
                   help="re-run a stored study from its file alone and compare bit for bit (no other option)")
    p.add_argument("--allow-model-change", action="store_true",
                   help="with --from-front: use the member even if the model code or parameters changed since "
                        "the study (the file records it)")


_MC_BYTES_PER_RUN = (6 + 6 + 4 + 6 + 1) * 8 + 8  # chat, rmse, factors, phase, t_fail, seed (+ ok)


def check_montecarlo(a: argparse.Namespace) -> None:
    from arvcas.io.cliargs import check_memory, refuse

    if a.check is not None:
        refuse(a, ("controller", "runs", "out", "seed", "spread", "config", "params", "from_front", "index",
                   "draws_toml", "allow_model_change", "force"),
               "--check FILE re-runs the file's own configuration: give no other option")
        return
    if a.from_front is None:
        refuse(a, ("index", "allow_model_change"), "only with --from-front")
    elif a.index is None:
        raise ValueError("--from-front needs --index I (or --index knee)")
    if a.draws_toml:
        refuse(a, ("out", "controller", "from_front", "config", "params", "force"),
               "--draws-toml only prints the draws of --runs, --seed and --spread")
        if a.runs is None:
            raise ValueError("--draws-toml: give --runs K")
        return
    if a.runs is None or a.out is None:
        raise ValueError("montecarlo: --runs N and --out FILE.h5 are required (or --check FILE.h5)")
    check_memory("montecarlo --runs", a.runs * _MC_BYTES_PER_RUN * 2)


def montecarlo_outputs(a: argparse.Namespace) -> list:
    if a.out is None or a.check is not None or a.draws_toml:
        return []
    from arvcas.experiments.montecarlo import FORMAT

    return [("--out", a.out, FORMAT), ("--out (its Markdown summary)", a.out.with_suffix(".md"))]


def run_montecarlo(a: argparse.Namespace) -> int:
    from arvcas.sim import scenario
    from arvcas.system.params import load
    from arvcas.experiments import _io
    from arvcas.experiments.montecarlo import read_montecarlo, reproduce, run_montecarlo, summary_markdown, write_montecarlo

    seed = 0 if a.seed is None else a.seed
    spread = 0.3 if a.spread is None else a.spread
    if a.check is not None:
        old = read_montecarlo(a.check)
        _say(f"re-running {old.runs} runs of {old.controller} (master seed {old.draws.master_seed}) ...")
        _new, diff = reproduce(a.check)
        return _report_check(a.check, diff, f"{old.runs} runs: draws, chat, rmse, ok, t_fail")
    if a.draws_toml:
        from arvcas.experiments.montecarlo import draw, draws_toml

        print(draws_toml(draw(a.runs, seed, spread)), end="")
        return 0
    out = _io.target(a.out, f"--out {a.out}")
    params = load(a.system)
    cfg = scenario.load_scenario(a.config if a.config is not None else params.default("scenario"))
    changed = None
    controller, gains, source, front_path = a.controller, None, None, None
    if a.from_front is not None:
        from arvcas.experiments.robust import front_member
        from arvcas.tuning.front import check_provenance, resolve_front_path

        changed = check_provenance(a.from_front, params, a.allow_model_change, "--from-front")
        controller_f, gains, cfg_text, source = front_member(a.from_front, a.index)

        front_path = str(resolve_front_path(a.from_front))
        if controller is not None and controller != controller_f:
            raise ValueError(f"--controller {controller} differs from the front's controller {controller_f}")
        controller = controller_f
        if a.config is None and cfg_text:
            cfg = scenario.loads_scenario(cfg_text, f"{a.from_front} (study scenario)")
    if controller is None:
        raise ValueError("--controller: required (proposed, agsta, traditional, implicit)")
    mc = run_montecarlo(controller, a.runs, seed, gains=gains, spread=spread, cfg=cfg, system=params,
                        gains_source=source, progress=_say)
    if front_path is not None:
        mc.meta["front_path"] = front_path
    if changed:
        mc.meta["model_change_allowed"] = changed
    write_montecarlo(mc, out)
    md = summary_markdown(mc)
    md_path = _io.write_text(out.with_suffix(".md"), md)
    print(md)
    print(f"wrote {out}\nwrote {md_path}")
    return 0


# ---- front robust (an action added to the tuning package's ``front`` command) ----------------------


def add_robust(r: argparse.ArgumentParser) -> None:
    r.add_argument("file", type=Path, help="front.h5 (or a study output directory)")
    r.add_argument("--runs", type=_runs, required=True, metavar="N", help="Monte Carlo draws per member")
    r.add_argument("--seed", type=_seed, default=0, help="master seed of the draws (default 0)")
    r.add_argument("--spread", type=float, default=0.3,
                   help="half-width of the nominal-model factors' draw around 1 (default 0.3)")
    r.add_argument("--out", type=Path, default=None, metavar="DIR", help="default: the front's directory")
    r.add_argument("--allow-model-change", action="store_true",
                   help="run even if the model code or parameters changed since the study (the file records it)")
    _add_format(r)


def _robust_dir(a: argparse.Namespace) -> Path:
    from arvcas.tuning.front import resolve_front_path

    return a.out if a.out is not None else resolve_front_path(a.file).parent


def robust_outputs(a: argparse.Namespace) -> list:
    d = _robust_dir(a)
    from arvcas.experiments.robust import FORMAT

    return [(f"--out {d}", d / f"robust.{e}", FORMAT if e == "h5" else None) for e in ("h5", "md", a.format or "png")]


def check_robust(a: argparse.Namespace) -> None:
    from arvcas.io.cliargs import check_memory

    from arvcas.tuning.checkpoint import read_checkpoint
    from arvcas.tuning.front import resolve_front_path

    c = read_checkpoint(resolve_front_path(a.file))
    members = 1 + (int(c.front.size) if c.X is not None else 0)
    check_memory("front robust --runs", members * a.runs * _MC_BYTES_PER_RUN * 2)


def run_robust(a: argparse.Namespace) -> int:
    from arvcas.experiments import _io
    from arvcas.experiments.robust import robust_front, robust_markdown, write_robust_dir
    from arvcas.tuning import checkpoint as ck
    from arvcas.tuning.front import check_provenance, resolve_front_path, system_params

    out = _robust_dir(a)
    _io.prepare_dir(out, f"--out {out}")
    params = system_params(ck.read_checkpoint(resolve_front_path(a.file)))  # the front's own system
    changed = check_provenance(a.file, params, a.allow_model_change, "front robust")
    rf = robust_front(a.file, a.runs, a.seed, a.spread, progress=_say, model_change=changed or "")
    files = write_robust_dir(rf, out, a.format or "png")
    print(robust_markdown(rf))
    for p in files.values():
        print(f"wrote {p}")
    return 0


# ---- front explore -----------------------------------------------------------------------------------


def _members(text: str):
    t = text.strip().lower()
    if t in ("all", "knee"):
        return t
    from arvcas.io.cliargs import count_arg

    return count_arg(1, 1_000_000, "--members")(text)


def add_explore(p: argparse.ArgumentParser) -> None:
    from arvcas.io.cliargs import count_arg

    p.add_argument("fronts", type=Path, nargs="+", metavar="DIR",
                   help="study output directories (every front in them) or front.h5 files, of one system and "
                        "one set of objectives")
    p.add_argument("--out", type=Path, required=True, metavar="FILE.html", help="the page (self-contained HTML)")
    p.add_argument("--members", type=_members, default="all", metavar="all|knee|N",
                   help="whose time responses the page stores: every member (default), the knee, or N members "
                        "spread along each front and its knee")
    p.add_argument("--samples", type=count_arg(2, 100_000, "--samples"), default=None, metavar="N",
                   help="samples kept of each time response (default 300: every k-th controller sample)")
    p.add_argument("--allow-model-change", action="store_true",
                   help="write the page even if the model code or parameters changed since the studies (the page "
                        "says whether the replays still reproduce the stored metrics)")


def check_explore(a: argparse.Namespace) -> None:
    if a.out.suffix.lower() not in (".html", ".htm"):
        raise ValueError(f"--out {a.out}: the page is HTML; name it FILE.html")
    try:
        import plotly  # noqa: F401
    except ImportError:
        raise ValueError("front explore: needs the plotly package (pip install 'arvcas[explore]')") from None


def explore_outputs(a: argparse.Namespace) -> list:
    return [("--out", a.out)]


def run_explore(a: argparse.Namespace) -> int:
    from arvcas.experiments import _io
    from arvcas.experiments.explore import DEFAULT_SAMPLES, write_page

    _io.target(a.out, f"--out {a.out}")
    out = write_page(a.fronts, a.out, members=a.members, samples=a.samples or DEFAULT_SAMPLES,
                     allow_model_change=a.allow_model_change, say=_say)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return 0


# ---- compare on Monte Carlo files ------------------------------------------------------------------


def _run_compare_mc(a: argparse.Namespace, kind: str) -> int:
    """``kind``: "montecarlo" (two Monte Carlo files) or "robust" (two robust.h5 of ``front robust``)."""
    from arvcas.io.cliargs import figure_file
    from arvcas.experiments import _io

    if kind == "montecarlo":
        from arvcas.experiments.montecarlo import compare_markdown as markdown, is_montecarlo_file as is_kind, plot_compare as plot
        from arvcas.experiments.montecarlo import read_montecarlo as read
        what = "Monte Carlo file"
    else:
        from arvcas.experiments.robust import compare_robust_markdown as markdown, is_robust_file as is_kind
        from arvcas.experiments.robust import plot_compare_robust as plot, read_robust as read
        what = "robust-front file (front robust)"
    for p in a.fronts:
        if not is_kind(p):
            raise ValueError(f"compare: {p} is not a {what} like the other; compare takes fronts, two Monte "
                             "Carlo files or two robust-front files")
    report = a.report
    for p in (report, a.plot):
        if p is not None:
            _io.target(p, f"{p}")
    fmt = figure_file(a.plot, a.format, f"--plot {a.plot}") if a.plot is not None else None
    ma, mb = read(a.fronts[0]), read(a.fronts[1])
    text = markdown(ma, mb)
    print(text)
    if report is not None:
        print(f"wrote {_io.write_text(report, text)}")
    if a.plot is not None:
        fig = plot(ma, mb)
        print(f"wrote {_io.write_figure(a.plot, fig, fmt)}")
    return 0


def add_compare(p: argparse.ArgumentParser) -> None:
    from arvcas.tuning.cli import add_compare as add_front_compare

    add_front_compare(p)
    p.add_argument("--report", type=Path, default=None, metavar="FILE.md",
                   help="Monte Carlo or robust-front files: also write the comparison as Markdown")


def _kind(a: argparse.Namespace) -> str:
    from arvcas.experiments.montecarlo import is_montecarlo_file
    from arvcas.experiments.robust import is_robust_file

    if any(is_montecarlo_file(p) for p in a.fronts):
        return "montecarlo"
    if any(is_robust_file(p) for p in a.fronts):
        return "robust"
    return "front"


def check_compare(a: argparse.Namespace) -> None:
    from arvcas.io.cliargs import refuse

    if a.plot is None:
        refuse(a, ("paper", "format"), "only with --plot")
    kind = _kind(a)
    if kind == "front":
        refuse(a, ("report",), "only for Monte Carlo or robust-front files")
        if len(a.fronts) < 2:
            raise ValueError(f"compare: needs two or more fronts, got {len(a.fronts)}")
    else:
        refuse(a, ("ref", "allow_model_change"), "only for fronts")
        if a.paper:
            raise ValueError("--paper: only for fronts")
        if len(a.fronts) != 2:
            raise ValueError(f"compare: Monte Carlo and robust-front files are compared two at a time, got "
                             f"{len(a.fronts)}")


def compare_outputs(a: argparse.Namespace) -> list:
    return [(lab, p) for lab, p in (("--plot", a.plot), ("--report", a.report)) if p is not None]


def run_compare(a: argparse.Namespace) -> int:
    """Fronts (the tuning package's comparison), two Monte Carlo files or two robust fronts."""
    kind = _kind(a)
    if kind == "front":
        from arvcas.tuning.cli import run_compare as run_front_compare

        return run_front_compare(a)
    return _run_compare_mc(a, kind)


# ---- knees ---------------------------------------------------------------------------------------


def add_knees(p: argparse.ArgumentParser) -> None:
    p.add_argument("study_dir", type=Path, metavar="STUDY_DIR",
                   help="the --out directory of arvcas tune (one front, or one per controller), or a front.h5")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="where to write (created if missing)")
    add_figure_format(p)


def knees_outputs(a):
    from arvcas.experiments.knees import front_controllers, output_files

    return output_kinds([(f"--out {a.out}", p) for p in output_files(a.out, front_controllers(a.study_dir), a.format or "png")],
                  RESULT_FORMATS)


def run_knees(a: argparse.Namespace) -> int:
    from arvcas.experiments.knees import replay_knees
    from arvcas.util import files

    files.prepare_dir(a.out, f"--out {a.out}")
    replay_knees(a.study_dir, a.out, fmt=a.format or "png")
    return 0


# ---- simulate ----------------------------------------------------------------------------------


def add_simulate(p: argparse.ArgumentParser) -> None:
    p.add_argument("--controller", default=None,
                   help="a controller: proposed, agsta, traditional, implicit, pid, or a plugin's (arvcas controllers; "
                        "required unless --from-front)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE.h5",
                   help="write the result here: HDF5 (.h5), or a MATLAB file if the name ends in .mat")
    p.add_argument("--seed", type=seed_arg, default=None, help="sensor-noise seed (default 0; 0 <= seed < 2**63)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="scenario file (default: the system's scenario)")
    p.add_argument("--from-front", type=Path, default=None, metavar="FRONT.h5",
                   help="replay a member of a tuning front (with --index)")
    p.add_argument("--index", type=int, default=None, help="front member to replay")
    p.add_argument("--allow-model-change", action="store_true",
                   help="with --from-front: replay even if the model code or parameters changed since the study "
                        "(the result records it)")
    add_model_args(p)


def check_simulate(a: argparse.Namespace) -> None:
    if a.from_front is None:
        refuse(a, ("index", "allow_model_change"), "only with --from-front")
    elif a.index is None:
        raise ValueError("--from-front needs --index I")


def _metrics_table(chat, rmse, held=(True,) * 6) -> str:
    from arvcas.controllers.gains import DOFS

    lines = [f"{'DOF':>6} {'CHAT':>12} {'RMSE':>12}"]
    for d, c, r, k in zip(DOFS, chat, rmse, held):
        lines.append(f"{d:>6} {c:12.5g} " + (f"{r:12.5g}" if k else f"{'not held':>12}"))
    return "\n".join(lines)


def _drift_note(cfg, eta) -> str | None:
    """Without a position fix (docs/sensors.md): what is held, and the horizontal drift, reported, not penalised."""
    from arvcas.controllers.gains import DOFS
    from arvcas.sim import scenario

    held = scenario.held_dofs(cfg)
    if all(held):
        return None
    import numpy as np

    xy = np.asarray(eta)[:, 0:2] - np.asarray(cfg.initial_eta_d)[0:2]
    d = np.hypot(xy[:, 0], xy[:, 1])
    return (f"held: {', '.join(n for n, k in zip(DOFS, held) if k)} (no position sensor); RMSE on those only. "
            f"horizontal drift (not held): {d[-1]:.4g} m at the end (x {xy[-1, 0]:+.4g}, y {xy[-1, 1]:+.4g} m), "
            f"at most {d.max():.4g} m")


def run_simulate(a: argparse.Namespace) -> int:
    from arvcas.io import results
    from arvcas.sim import scenario
    from arvcas.system.params import load
    from arvcas.sim.simulation import simulate

    if a.out is not None:
        results.check_dir(a.out.parent, f"--out {a.out}")
    params = load(a.system)
    if a.from_front is not None and a.system is None:  # the front's own system
        from arvcas.tuning import checkpoint as ck
        from arvcas.tuning.front import resolve_front_path, system_params

        params = system_params(ck.read_checkpoint(resolve_front_path(a.from_front)))
    cfg = scenario.load_scenario(a.config if a.config is not None else params.default("scenario"))
    gains = None
    controller, seed = a.controller, a.seed
    if a.from_front is not None:
        from arvcas.tuning.front import check_provenance, member_gains

        changed = check_provenance(a.from_front, params, a.allow_model_change, "--from-front")
        controller_f, gains, seed_f, cfg_text = member_gains(a.from_front, a.index)
        if controller is not None and controller != controller_f:
            raise ValueError(f"--controller {controller} differs from the front's controller {controller_f}")
        controller = controller_f
        seed = seed_f if seed is None else seed
        if a.config is None and cfg_text:
            cfg = scenario.loads_scenario(cfg_text, f"{a.from_front} (study scenario)")
    if controller is None:
        raise ValueError("--controller: required (proposed, agsta, traditional, implicit, pid, or a plugin's: "
                         "arvcas controllers)")
    r = simulate(controller, gains=gains, seed=0 if seed is None else seed, system=params, cfg=cfg,
                 opts=model_options(a.n_quad))
    if a.from_front is not None and changed:
        r.meta["model_change_allowed"] = changed
        print(f"note: replayed under another model than the study's ({changed}), as allowed by --allow-model-change")
    status = "ok" if r.ok else f"DIVERGED at t = {r.t_fail:g} s" + (
        f": {r.meta['failure']}" if r.meta.get("failure") else "")
    print(f"{controller}: seed {r.seed}, {r.t[-1]:g} s, {status}")
    print(_metrics_table(r.chat, r.rmse, scenario.held_dofs(cfg)))
    if (note := _drift_note(cfg, r.eta)) is not None:
        print(note)
    if a.out is not None and a.out.suffix == ".mat":
        from arvcas.io.matfile import write_result_mat

        print(f"wrote {write_result_mat(r, a.out)}")
    elif a.out is not None:
        print(f"wrote {results.write_result(r, a.out)}")
    return 0 if r.ok else 1


# ---- paper -------------------------------------------------------------------------------------


def add_paper(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    p.add_argument("--seed", type=seed_arg, default=0, help="sensor-noise seed shared by the runs (default 0)")
    add_figure_format(p, "Figures 5-11")


def run_paper(a: argparse.Namespace) -> int:
    from arvcas.experiments.paper import run_paper

    out = run_paper(a.out, seed=a.seed, fmt=a.format or "png")
    print((a.out / "table3.md").read_text())
    # the job succeeded when every run completed; whether the paper's comparison reproduces is
    # a finding, reported in table3.md, not an error
    return 0 if all(r.ok for r in out["results"].values()) else 1


def paper_outputs(a):
    from arvcas.experiments.paper import output_files

    return output_kinds([(f"--out {a.out}", p) for p in output_files(a.out, fmt=a.format or "png")], RESULT_FORMATS)
