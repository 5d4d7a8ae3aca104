"""The ``arvcas`` command: parse arguments, call a library function with typed arguments, print.

Subcommands live in :data:`COMMANDS` (name -> :class:`Command`); add one by writing an ``_add_*``
function for its arguments and a ``_run_*`` function taking the parsed namespace and returning the exit
code. Library errors (ValueError and subclasses such as ``ParamsError``, ``CacheError``) and OS errors
are printed as one line ``arvcas: error: ...`` with exit code 2, without a traceback.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

__all__ = ["main", "COMMANDS", "Command"]


@dataclass(frozen=True)
class Command:
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


def _model_options(n_quad: int):
    from arvcas.model.uvms import ModelOptions

    return ModelOptions(n_quad=n_quad)


def _add_model_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", metavar="FILE", type=Path, default=None,
                   help="parameter file (default: the packaged haidou1.toml)")
    p.add_argument("--n-quad", metavar="N", type=int, default=5,
                   help="Gauss-Legendre points per link for the drag integral (default: 5)")


# ---- export-c ----------------------------------------------------------------------------------


def _add_export_c(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", type=Path, help="output directory (created if its parent exists)")
    p.add_argument("--prefix", default="arvcas_haidou1_",
                   help="prefix of every C symbol; the library is lib<prefix without its last _>.so (default: arvcas_haidou1_)")
    p.add_argument("--force", action="store_true",
                   help="replace files in DIR that export-c did not write, or that were changed since")
    _add_model_args(p)


def _run_export_c(a: argparse.Namespace) -> int:
    from arvcas.build.export import export_c
    from arvcas.params import load

    paths = export_c(a.dir, opts=_model_options(a.n_quad), params=load(a.params), prefix=a.prefix, force=a.force)
    for path in paths:
        print(path)
    print(f"build with: make -C {a.dir}")
    return 0


# ---- cache -------------------------------------------------------------------------------------


def _add_cache(p: argparse.ArgumentParser) -> None:
    pass


def _run_cache(a: argparse.Namespace) -> int:
    from arvcas.build.codegen import cache_info

    d, arts = cache_info()
    print(f"cache: {d}")
    if not arts:
        print("(no artifacts)")
        return 0
    w = max(len(x.name) for x in arts)
    print(f"{'function':<{w}}  {'size KiB':>9}  {'compile s':>9}  {'verified':>8}  flags / file")
    for x in arts:
        flags = " ".join(f for f in x.flags if f not in ("-shared", "-fPIC"))
        print(f"{x.name:<{w}}  {x.size_bytes / 1024:9.1f}  {x.compile_time_s:9.2f}  {'yes' if x.verified else 'NO':>8}"
              f"  {flags}  {x.path.name}")
    print(f"{len(arts)} artifact(s), {sum(x.size_bytes for x in arts) / 1024:.1f} KiB")
    return 0


# ---- demo --------------------------------------------------------------------------------------

_Q0_DEG = (90.0, 90.0, -90.0, 0.0, 90.0, 0.0)
_QG_DEG = (60.0, 60.0, -60.0, 0.0, 60.0, 0.0)


def _quintic(t: float, q0, qg, t0: float, t1: float):
    """Rest-to-rest quintic from q0 (t <= t0) to qg (t >= t1): (q, qd, qdd), elementwise."""
    T = t1 - t0
    s = min(max((t - t0) / T, 0.0), 1.0)
    pos = 10 * s**3 - 15 * s**4 + 6 * s**5
    vel = (30 * s**2 - 60 * s**3 + 30 * s**4) / T
    acc = (60 * s - 180 * s**2 + 120 * s**3) / T**2
    q = [a + (b - a) * pos for a, b in zip(q0, qg)]
    qd = [(b - a) * vel for a, b in zip(q0, qg)]
    qdd = [(b - a) * acc for a, b in zip(q0, qg)]
    return q, qd, qdd


def demo_table(params_path: Path | None = None, n_quad: int = 5, t_end: float = 25.0, dt: float = 1.0):
    """Coupling wrench tau_m (N, N m; in {b} about the COB) along the demo arm motion.

    The arm moves from q0 = [90, 90, -90, 0, 90, 0] deg to qg = [60, 60, -60, 0, 60, 0] deg by a
    quintic over 5..20 s; the vehicle is at rest and level, payload 0. Returns rows (t, Fx..Mz).
    """
    import numpy as np

    from arvcas.build.codegen import compiled
    from arvcas.params import load

    p = load(params_path).vector()
    f = compiled("arm_wrench", _model_options(n_quad))
    q0 = [math.radians(v) for v in _Q0_DEG]
    qg = [math.radians(v) for v in _QG_DEG]
    z6 = np.zeros(6)
    rows = []
    for k in range(int(round(t_end / dt)) + 1):
        t = k * dt
        q, qd, qdd = _quintic(t, q0, qg, 5.0, 20.0)
        tau_m = np.asarray(f(z6, z6, z6, q, qd, qdd, 0.0, p)).ravel()
        rows.append((t, *tau_m))
    return rows


def _add_demo(p: argparse.ArgumentParser) -> None:
    _add_model_args(p)


def _run_demo(a: argparse.Namespace) -> int:
    rows = demo_table(a.params, a.n_quad)
    print("coupling wrench tau_m of the arm on the vehicle ({b}, about the COB), vehicle at rest and level,")
    print("arm q0 = [90 90 -90 0 90 0] deg -> qg = [60 60 -60 0 60 0] deg by a quintic over 5..20 s, payload 0")
    cols = ("t [s]", "Fx [N]", "Fy [N]", "Fz [N]", "Mx [N m]", "My [N m]", "Mz [N m]")
    print("".join(f"{c:>12}" for c in cols))
    for r in rows:
        print(f"{r[0]:12.1f}" + "".join(f"{v:12.4f}" for v in r[1:]))
    return 0


# ---- simulate ----------------------------------------------------------------------------------


def _add_simulate(p: argparse.ArgumentParser) -> None:
    p.add_argument("--controller", default=None,
                   help="proposed, agsta, traditional or implicit (required unless --from-front)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE.h5", help="write the result here (HDF5)")
    p.add_argument("--seed", type=int, default=None, help="sensor-noise seed (default 0)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="scenario file (default: the packaged scenario.toml)")
    p.add_argument("--from-front", type=Path, default=None, metavar="FRONT.h5",
                   help="replay a member of a tuning front (with --index)")
    p.add_argument("--index", type=int, default=None, help="front member to replay")
    _add_model_args(p)


def _metrics_table(chat, rmse) -> str:
    from arvcas.controllers.gains import DOFS

    lines = [f"{'DOF':>6} {'CHAT':>12} {'RMSE':>12}"]
    for d, c, r in zip(DOFS, chat, rmse):
        lines.append(f"{d:>6} {c:12.5g} {r:12.5g}")
    return "\n".join(lines)


def _run_simulate(a: argparse.Namespace) -> int:
    from arvcas.io import results
    from arvcas.sim import scenario
    from arvcas.params import load
    from arvcas.sim.simulation import simulate

    if a.out is not None:
        results.check_dir(a.out.parent if str(a.out.parent) else Path("."), f"--out {a.out}")
    cfg = scenario.load_scenario(a.config)
    gains = None
    controller, seed = a.controller, a.seed
    if a.from_front is not None:
        from arvcas.tuning.front import member_gains

        if a.index is None:
            raise ValueError("--from-front needs --index I")
        controller_f, gains, seed_f, cfg_text = member_gains(a.from_front, a.index)
        if controller is not None and controller != controller_f:
            raise ValueError(f"--controller {controller} differs from the front's controller {controller_f}")
        controller = controller_f
        seed = seed_f if seed is None else seed
        if a.config is None and cfg_text:
            cfg = scenario.loads_scenario(cfg_text, f"{a.from_front} (study scenario)")
    if controller is None:
        raise ValueError("--controller: required (proposed, agsta, traditional, implicit)")
    r = simulate(controller, gains=gains, seed=0 if seed is None else seed, params=load(a.params), cfg=cfg,
                 opts=_model_options(a.n_quad))
    status = "ok" if r.ok else f"DIVERGED at t = {r.t_fail:g} s"
    print(f"{controller}: seed {r.seed}, {r.t[-1]:g} s, {status}")
    print(_metrics_table(r.chat, r.rmse))
    if a.out is not None:
        print(f"wrote {results.write_result(r, a.out)}")
    return 0 if r.ok else 1


# ---- paper -------------------------------------------------------------------------------------


def _add_paper(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed shared by the runs (default 0)")


def _run_paper(a: argparse.Namespace) -> int:
    from arvcas.experiments.paper import run_paper

    out = run_paper(a.out, seed=a.seed)
    print((a.out / "table3.md").read_text())
    # the job succeeded when every run completed; whether the paper's comparison reproduces is
    # a finding, reported in table3.md, not an error
    return 0 if all(r.ok for r in out["results"].values()) else 1


# ---- bench -------------------------------------------------------------------------------------


def _add_bench(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quick", action="store_true", help="tiny repetition counts, no opt-level sweep (CI check)")
    p.add_argument("--out", type=Path, default=Path("results"), metavar="DIR",
                   help="where bench.json and bench.md go (default: results/)")
    p.add_argument("--wait-load", type=float, default=None, metavar="L",
                   help="first wait (up to 15 min) until the 1-min load average is at most L")


def bench_module():
    """``benchmarks/bench.py`` of the source checkout this package runs from (not part of the package)."""
    import importlib

    root = Path(__file__).resolve().parents[1]
    if not (root / "benchmarks" / "bench.py").is_file():
        raise ValueError(f"bench: needs a source checkout of arvcas ({root / 'benchmarks' / 'bench.py'} not found)")
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    return importlib.import_module("benchmarks.bench")


def _run_bench(a: argparse.Namespace) -> int:
    run = bench_module().run
    run(a.out, quick=a.quick, wait_load=a.wait_load)
    print(f"wrote {a.out / 'bench.json'} and {a.out / 'bench.md'}")
    return 0


COMMANDS: dict[str, Command] = {
    "export-c": Command("write the plant functions as a C library with Makefile, example and README",
                        _add_export_c, _run_export_c),
    "cache": Command("show the build cache directory and its compiled libraries", _add_cache, _run_cache),
    "demo": Command("print the arm's coupling wrench on the vehicle along a simple arm motion",
                    _add_demo, _run_demo),
    "simulate": Command("run the station-keeping experiment once and print CHAT/RMSE per DOF",
                        _add_simulate, _run_simulate),
    "paper": Command("the paper's experiment end to end: three controllers, Table 3, Figures 5-11",
                     _add_paper, _run_paper),
    "bench": Command("measure plant, closed-loop and compile speed; write bench.json and bench.md",
                     _add_bench, _run_bench),
}
__import__("arvcas.tuning.cli", fromlist=["register"]).register(COMMANDS)  # tune, front, compare (arvcas/tuning)
__import__("arvcas.experiments.cli", fromlist=["register"]).register(COMMANDS)  # after tuning: extends front, compare


def _parser() -> argparse.ArgumentParser:
    from arvcas import __version__

    ap = argparse.ArgumentParser(prog="arvcas", description="Haidou-1 ARV + manipulator: CasADi models compiled to C")
    ap.add_argument("--version", action="version", version=f"arvcas {__version__}")
    ap.add_argument("-v", "--verbose", action="store_true", help="log progress (compiles, cache hits)")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, cmd in COMMANDS.items():
        sp = sub.add_parser(name, help=cmd.help, description=cmd.help)
        cmd.add_arguments(sp)
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run the ``arvcas`` command line; returns the exit code (0 ok, 2 usage or library error)."""
    ap = _parser()
    try:
        a = ap.parse_args(argv)
    except SystemExit as e:  # --help, --version, usage errors: argparse has printed the message
        return e.code if isinstance(e.code, int) else 2
    if a.verbose:
        import logging

        logging.basicConfig(level=logging.INFO, format="arvcas: %(message)s")
    try:
        return COMMANDS[a.command].run(a)
    except (ValueError, OSError) as e:
        msg = " ".join(str(e).split()) or type(e).__name__
        print(f"arvcas: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("arvcas: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
