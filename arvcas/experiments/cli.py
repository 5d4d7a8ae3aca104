"""Command-line entries of :mod:`arvcas.experiments`: ``sweep``, ``montecarlo``, ``front robust`` and
``compare`` on Monte Carlo files.

:func:`register` adds ``sweep`` and ``montecarlo`` to :data:`arvcas.cli.COMMANDS` and extends the
tuning package's commands, which must be registered first: ``front`` gains the action ``robust``
(through argparse's public API: the ``front`` parser's sub-parsers action is captured while the
tuning package builds it) and ``compare`` dispatches on the file type (two fronts: the tuning
package's comparison; two Monte Carlo files: :func:`arvcas.experiments.montecarlo.compare_markdown`).
No file of the tuning package is edited. Each ``_run_*`` calls a library function with typed
arguments; errors are ValueError/OSError (one line via arvcas.cli).
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["register"]


def _floats(text: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got '{text}'") from None


def _ints(text: str) -> list[int]:
    try:
        if ".." in text:  # a range A..B (inclusive)
            a, b = text.split("..", 1)
            return list(range(int(a), int(b) + 1))
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers or A..B, got '{text}'") from None


def _names(text: str) -> list[str]:
    return [x.strip() for x in text.split(",") if x.strip()]


def _say(msg: str) -> None:
    print(msg, flush=True)


# ---- sweep -------------------------------------------------------------------------------------


def _add_sweep(p: argparse.ArgumentParser) -> None:
    p.add_argument("--h", type=_floats, default=None, metavar="H1,H2,...",
                   help="controller sampling periods in s (whole multiples of the plant step 0.01 s)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR", help="writes DIR/sweep.h5, sweep.md, sweep.png")
    p.add_argument("--controllers", type=_names, default=None, metavar="A,B,...",
                   help="default: proposed, traditional, implicit, agsta")
    p.add_argument("--seeds", type=_ints, default=[0], metavar="S1,S2|A..B", help="noise seeds (default 0)")
    p.add_argument("--noise-scale", type=float, default=1.0, metavar="X",
                   help="multiply the sensor noise by X (0: perfect measurements, the EKF unchanged; default 1)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE", help="scenario file (default: packaged)")
    p.add_argument("--params", type=Path, default=None, metavar="FILE", help="parameter file (default: packaged)")
    p.add_argument("--check", type=Path, default=None, metavar="FILE.h5",
                   help="re-run a stored sweep from its file alone and compare bit for bit (no other option)")


def _run_sweep(a: argparse.Namespace) -> int:
    from arvcas.sim import scenario
    from arvcas.params import load
    from arvcas.experiments import _io
    from arvcas.experiments.sweep import CONTROLLERS, reproduce_sweep, run_sweep, sweep_markdown, write_sweep_dir

    if a.check is not None:
        if a.h is not None or a.out is not None:
            raise ValueError("--check FILE re-runs the file's own configuration: give no --h or --out")
        _say(f"re-running {a.check} ...")
        _new, diff = reproduce_sweep(a.check)
        if diff:
            print(f"{a.check}: NOT reproduced: {', '.join(diff)} differ")
            return 1
        print(f"{a.check}: reproduced bit for bit (chat, rmse, ok, t_fail, zigzag measures, k1 series)")
        return 0
    if a.h is None or a.out is None:
        raise ValueError("sweep: --h H1,H2,... and --out DIR are required (or --check FILE.h5)")
    _io.prepare_dir(a.out, f"--out {a.out}")
    sw = run_sweep(a.h, a.controllers or CONTROLLERS, a.seeds, cfg=scenario.load_scenario(a.config),
                   params=load(a.params), noise_scale=a.noise_scale, progress=_say)
    files = write_sweep_dir(sw, a.out)
    print(sweep_markdown(sw).split("\n## ", 1)[0])
    for p in files.values():
        print(f"wrote {p}")
    return 0


# ---- montecarlo --------------------------------------------------------------------------------


def _add_montecarlo(p: argparse.ArgumentParser) -> None:
    p.add_argument("--controller", default=None, help="proposed, agsta, traditional or implicit")
    p.add_argument("--runs", type=int, default=None, metavar="N", help="number of draws")
    p.add_argument("--out", type=Path, default=None, metavar="FILE.h5",
                   help="result file; a summary FILE.md is written next to it")
    p.add_argument("--seed", type=int, default=0, help="master seed of the draws (default 0)")
    p.add_argument("--spread", type=float, default=0.3,
                   help="half-width of the nominal-model factors' uniform draw around 1 (default 0.3: +-30 %%)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE", help="scenario file (default: packaged)")
    p.add_argument("--params", type=Path, default=None, metavar="FILE", help="parameter file (default: packaged)")
    p.add_argument("--from-front", type=Path, default=None, metavar="FRONT",
                   help="use the gains of a tuning front member (with --index)")
    p.add_argument("--index", default=None, help="front member: an integer, or 'knee'")
    p.add_argument("--draws-toml", action="store_true",
                   help="print the --runs draws of --seed as [[evaluation.draws]] tables for a tuning study file "
                        "(optimise the mean over K draws) and exit")
    p.add_argument("--check", type=Path, default=None, metavar="FILE.h5",
                   help="re-run a stored study from its file alone and compare bit for bit (no other option)")


def _run_montecarlo(a: argparse.Namespace) -> int:
    from arvcas.sim import scenario
    from arvcas.params import load
    from arvcas.experiments import _io
    from arvcas.experiments.montecarlo import read_montecarlo, reproduce, run_montecarlo, summary_markdown, write_montecarlo

    if a.check is not None:
        if any(v is not None for v in (a.controller, a.runs, a.out, a.from_front)):
            raise ValueError("--check FILE re-runs the file's own configuration: give no other study option")
        old = read_montecarlo(a.check)
        _say(f"re-running {old.runs} runs of {old.controller} (master seed {old.draws.master_seed}) ...")
        _new, diff = reproduce(a.check)
        if diff:
            print(f"{a.check}: NOT reproduced: {', '.join(diff)} differ")
            return 1
        print(f"{a.check}: reproduced bit for bit ({old.runs} runs: draws, chat, rmse, ok, t_fail)")
        return 0
    if a.draws_toml:
        from arvcas.experiments.montecarlo import draw, draws_toml

        if a.runs is None:
            raise ValueError("--draws-toml: give --runs K")
        print(draws_toml(draw(a.runs, a.seed, a.spread)), end="")
        return 0
    if a.runs is None or a.out is None:
        raise ValueError("montecarlo: --runs N and --out FILE.h5 are required (or --check FILE.h5)")
    out = _io.target(a.out, f"--out {a.out}")
    cfg = scenario.load_scenario(a.config)
    controller, gains, source, front_path = a.controller, None, None, None
    if a.from_front is not None:
        from arvcas.experiments.robust import front_member

        if a.index is None:
            raise ValueError("--from-front needs --index I (or --index knee)")
        controller_f, gains, cfg_text, source = front_member(a.from_front, a.index)
        from arvcas.tuning.front import resolve_front_path

        front_path = str(resolve_front_path(a.from_front))
        if controller is not None and controller != controller_f:
            raise ValueError(f"--controller {controller} differs from the front's controller {controller_f}")
        controller = controller_f
        if a.config is None and cfg_text:
            cfg = scenario.loads_scenario(cfg_text, f"{a.from_front} (study scenario)")
    if controller is None:
        raise ValueError("--controller: required (proposed, agsta, traditional, implicit)")
    mc = run_montecarlo(controller, a.runs, a.seed, gains=gains, spread=a.spread, cfg=cfg, params=load(a.params),
                        gains_source=source, progress=_say)
    if front_path is not None:
        mc.meta["front_path"] = front_path
    write_montecarlo(mc, out)
    md = summary_markdown(mc)
    md_path = _io.write_text(out.with_suffix(".md"), md)
    print(md)
    print(f"wrote {out}\nwrote {md_path}")
    return 0


# ---- front robust (an action added to the tuning package's ``front`` command) ----------------------


class _CaptureSubparsers:
    """A parser proxy that records the sub-parsers action another ``add_arguments`` creates, so that
    one more action can be added to it through argparse's public API."""

    def __init__(self, parser: argparse.ArgumentParser):
        self._parser = parser
        self.subparsers = None

    def add_subparsers(self, *args, **kwargs):
        self.subparsers = self._parser.add_subparsers(*args, **kwargs)
        return self.subparsers

    def __getattr__(self, name):
        return getattr(self._parser, name)


def _add_robust(sub) -> None:
    r = sub.add_parser("robust", help="re-evaluate every front member under Monte Carlo; mark the robust "
                                      "non-dominated ones (robust.h5, robust.md, robust.png)")
    r.add_argument("file", type=Path, help="front.h5 (or a study output directory)")
    r.add_argument("--runs", type=int, required=True, metavar="N", help="Monte Carlo draws per member")
    r.add_argument("--seed", type=int, default=0, help="master seed of the draws (default 0)")
    r.add_argument("--spread", type=float, default=0.3,
                   help="half-width of the nominal-model factors' draw around 1 (default 0.3)")
    r.add_argument("--out", type=Path, default=None, metavar="DIR", help="default: the front's directory")


def _run_robust(a: argparse.Namespace) -> int:
    from arvcas.tuning.front import resolve_front_path
    from arvcas.experiments import _io
    from arvcas.experiments.robust import robust_front, robust_markdown, write_robust_dir

    out = a.out if a.out is not None else resolve_front_path(a.file).parent
    _io.prepare_dir(out, f"--out {out}")
    rf = robust_front(a.file, a.runs, a.seed, a.spread, progress=_say)
    files = write_robust_dir(rf, out)
    print(robust_markdown(rf))
    for p in files.values():
        print(f"wrote {p}")
    return 0


def _with_robust(front):
    """The tuning package's ``front`` command with the ``robust`` action added."""
    from arvcas.cli import Command

    def add(p: argparse.ArgumentParser) -> None:
        cap = _CaptureSubparsers(p)
        front.add_arguments(cap)
        if cap.subparsers is None:
            raise RuntimeError("arvcas.experiments: the 'front' command has no actions to extend")
        _add_robust(cap.subparsers)

    def run(a: argparse.Namespace) -> int:
        return _run_robust(a) if a.action == "robust" else front.run(a)

    return Command(front.help.replace("export (csv, json) or plot", "export (csv, json), plot or robust (Monte Carlo)"),
                   add, run)


# ---- compare on Monte Carlo files ------------------------------------------------------------------


def _run_compare_mc(a: argparse.Namespace, kind: str) -> int:
    """``kind``: "montecarlo" (two Monte Carlo files) or "robust" (two robust.h5 of ``front robust``)."""
    from arvcas.experiments import _io

    if kind == "montecarlo":
        from arvcas.experiments.montecarlo import compare_markdown as markdown, is_montecarlo_file as is_kind, plot_compare as plot
        from arvcas.experiments.montecarlo import read_montecarlo as read
        what = "Monte Carlo file"
    else:
        from arvcas.experiments.robust import compare_robust_markdown as markdown, is_robust_file as is_kind
        from arvcas.experiments.robust import plot_compare_robust as plot, read_robust as read
        what = "robust-front file (front robust)"
    for p in (a.a, a.b):
        if not is_kind(p):
            raise ValueError(f"compare: {p} is not a {what} like the other; compare takes two fronts, two Monte "
                             "Carlo files or two robust-front files")
    if getattr(a, "ref", None) is not None:
        raise ValueError("--ref: only for fronts")
    report = getattr(a, "report", None)
    for p in (report, a.plot):
        if p is not None:
            _io.target(p, f"{p}")
    ma, mb = read(a.a), read(a.b)
    text = markdown(ma, mb)
    print(text)
    if report is not None:
        print(f"wrote {_io.write_text(report, text)}")
    if a.plot is not None:
        fig = plot(ma, mb)
        print(f"wrote {_io.atomic_write(a.plot, lambda p: fig.savefig(p, format='png', dpi=130))}")
    return 0


def _with_montecarlo_compare(compare):
    """The tuning package's ``compare`` command, dispatching to the paired Monte Carlo comparison when
    given Monte Carlo files (``format = "arvcas-montecarlo"``) instead of fronts."""
    from arvcas.cli import Command

    def add(p: argparse.ArgumentParser) -> None:
        compare.add_arguments(p)
        p.add_argument("--report", type=Path, default=None, metavar="FILE.md",
                       help="Monte Carlo or robust-front files: also write the comparison as Markdown")

    def run(a: argparse.Namespace) -> int:
        from arvcas.experiments.montecarlo import is_montecarlo_file
        from arvcas.experiments.robust import is_robust_file

        if is_montecarlo_file(a.a) or is_montecarlo_file(a.b):
            return _run_compare_mc(a, "montecarlo")
        if is_robust_file(a.a) or is_robust_file(a.b):
            return _run_compare_mc(a, "robust")
        if a.report is not None:
            raise ValueError("--report: only for Monte Carlo or robust-front files")
        return compare.run(a)

    return Command(compare.help + "; or two Monte Carlo files (per-DOF differences with 95 percent intervals); "
                   "or two robust fronts (front robust)", add, run)


def register(commands: dict) -> None:
    """Add this package's subcommands to the ``arvcas`` command registry (``arvcas.cli.COMMANDS``)."""
    from arvcas.cli import Command

    commands["sweep"] = Command(
        "every controller at several controller sampling periods: CHAT, RMSE, zigzag of k1 (table, plot)",
        _add_sweep, _run_sweep)
    commands["montecarlo"] = Command(
        "Monte Carlo over noise seeds, nominal-model factors (+-30 percent) and disturbance phases: CIs, failure rate",
        _add_montecarlo, _run_montecarlo)
    # extend the tuning package's commands when it is registered (before this call in arvcas/cli.py)
    if "front" in commands:
        commands["front"] = _with_robust(commands["front"])
    if "compare" in commands:
        commands["compare"] = _with_montecarlo_compare(commands["compare"])
