"""The ``arvcas`` command: one table of every command, the policies applied to each, and dispatch.

:data:`TABLE` lists every command and sub-command (``"front export"``) as a :class:`Command`: its
name, help, ``add_arguments`` and ``run`` (the handlers live with their packages: here, in
:mod:`arvcas.tuning.cli`, :mod:`arvcas.experiments.cli` (``simulate``, ``paper``, ``knees``, ...) and
:mod:`arvcas.experiments.validation`), the arguments that are input files,
the files it will write and a ``check`` of the options that do not apply. :func:`main` parses, then,
before calling ``run``:

* input policy (:func:`arvcas.util.files.check_input`): every declared input is a regular file
  (a front may also be a study directory); FIFOs, devices and directories are refused by name;
* output policy (:func:`arvcas.util.files.check_outputs`): no output is an input or another output,
  none is a special file, an existing file arvcas did not write is refused without ``--force``
  (added to every command that writes); stale temporary files of killed runs are removed;
* bounds: counts, seeds and timeouts are checked by their argparse types (:mod:`arvcas.io.cliargs`:
  ``seed_arg``, ``count_arg``, ``seconds_arg``) and the memory a request would take by the command's check.

A compile that takes more than a second prints a progress line on standard error
(:func:`arvcas.build.codegen.report_progress`). Errors (ValueError and subclasses, OSError) are printed
as one line ``arvcas: error: ...`` with exit code 2, usage errors likewise (``arvcas: error: CMD: argument ...``); SIGTERM and SIGHUP end the
command like Ctrl-C (temporary files removed), exit 128 + signal.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from arvcas.io.cliargs import (RESULT_FORMATS, add_model_args, add_system_arg, default_system_text, model_options,
                                out_file, refuse)
from arvcas.system import DEFAULT

__all__ = ["main", "TABLE", "COMMANDS", "Command"]

Paths = Callable[[argparse.Namespace], list]


@dataclass(frozen=True)
class Command:
    """One command of the table. ``inputs``: ``(dest, kind[, what])`` of arguments that name input files
    (kind ``"file"``, ``"system"``: a shipped system's name or a system file, ``"front"``: a front.h5
    or a study directory holding one, or ``"description"``: a file or a folder; ``what`` names the file
    in messages, default "file"); ``outputs``: the
    ``(label, path)`` files the command will write, from the parsed arguments; ``check``: raises
    ValueError for options that do not apply or requests too large, before any work; ``plugins``: the
    command takes a controller, and so ``--plugin MODULE|FILE.py`` (repeatable), loaded before ``check``."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    inputs: tuple = ()
    outputs: Paths | None = None
    check: Callable[[argparse.Namespace], None] | None = None
    plugins: bool = False


# ---- export-c ----------------------------------------------------------------------------------


def _add_export_c(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", type=Path, help="output directory (created if its parent exists)")
    p.add_argument("--prefix", default=None,
                   help="prefix of every C symbol; the library is lib<prefix without its last _>.so "
                        f"(default: arvcas_<system>_, e.g. arvcas_{DEFAULT}_)")
    add_model_args(p)


def _export_c_outputs(a: argparse.Namespace) -> list:
    from arvcas.build.export import KIND, default_prefix, files

    return [(f"DIR {a.dir}", a.dir / n, KIND, a.dir) for n in files(a.prefix or default_prefix(a.system))]


def _run_export_c(a: argparse.Namespace) -> int:
    from arvcas.build.export import export_c
    from arvcas.system.params import load

    paths = export_c(a.dir, opts=model_options(a.n_quad), system=load(a.system), prefix=a.prefix, force=a.force)
    for path in paths:
        print(path)
    print(f"build with: make -C {a.dir}")
    return 0


# ---- export-controller --------------------------------------------------------------------------


def _run_export_ardusub_params(a: argparse.Namespace, d: dict) -> int:
    """``--format ardusub-params``: the member's gains as an ArduSub .param file (arvcas.io.ardusub_params)."""
    from arvcas.controllers.gains import default_gains
    from arvcas.io import ardusub_params as ap

    if d["controller"] != "ardusub":
        raise ValueError(f"--format ardusub-params: the controller is {d['controller']}, not ardusub (tune the ardusub "
                         "controller; other laws export as a C library)")
    gains = d["gains"] if d["gains"] is not None else default_gains("ardusub", d["system"])
    ap.param_values(gains)  # a value outside ArduSub's ranges: refused before anything is written
    a.dir.mkdir(exist_ok=True)
    system = d["system"].structure.name
    path = ap.write_param_file(a.dir / ap.default_name(system), gains, system=system,
                               front=str(a.front) if a.front is not None else "none (ArduSub's defaults)",
                               member=str(a.member) if a.member is not None else "none",
                               objectives=d["gains_source"] or "ArduSub's default gains", force=a.force)
    print(path)
    return 0


def _member_arg(text: str):
    """``knee`` or an integer index of a front member."""
    if text == "knee":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected knee or an integer member index, got {text!r}") from None


def _add_export_controller(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", type=Path, help="output directory (created if its parent exists)")
    p.add_argument("--controller", default=None,
                   help="a controller: proposed, agsta, traditional, implicit, pid, or a plugin's (arvcas controllers; "
                        "required unless --front)")
    p.add_argument("--front", type=Path, default=None, metavar="FRONT",
                   help="a tuning front (front.h5 or the study directory of one controller): export one member's gains "
                        "with the front's controller, system and scenario (with --member)")
    p.add_argument("--member", type=_member_arg, default=None, metavar="knee|INDEX",
                   help="with --front: its knee (the rule of arvcas knees) or member INDEX (sorted by f_chat)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="scenario file: the sampling period, the reference's timing and the default set point, nominal "
                        "factors and EKF tuning (default: the front's study scenario, else the system's)")
    p.add_argument("--allow-model-change", action="store_true",
                   help="with --front: export even if the model code or parameters changed since the study (the "
                        "export's README and header record it)")
    p.add_argument("--prefix", default=None,
                   help="prefix of every C symbol; the library is lib<prefix without its last _>.so "
                        f"(default: arvcas_<system>_<controller>_, e.g. arvcas_{DEFAULT}_proposed_)")
    p.add_argument("--format", choices=("c", "ardusub-params"), default="c",
                   help="c: the C library (default); ardusub-params: the ardusub controller's gains as an ArduSub "
                        ".param file (QGroundControl, MAVProxy) in DIR, values outside ArduSub's ranges refused "
                        "(docs/ardusub.md)")
    add_system_arg(p, f"the front's, else {default_system_text()}")


def _check_export_controller(a: argparse.Namespace) -> None:
    from arvcas.controllers.gains import check_controller

    if a.front is None:
        refuse(a, ("member", "allow_model_change"), "only with --front")
        if a.controller is None:
            raise ValueError("--controller: required unless --front (proposed, agsta, traditional, implicit, pid)")
    elif a.member is None:
        raise ValueError("--front needs --member knee|INDEX")
    if a.controller is not None:
        check_controller(a.controller)


def _export_controller_design(a: argparse.Namespace) -> dict:
    """What to export, from the arguments (memoised on ``a``): controller, system, scenario, gains and
    where they come from."""
    if getattr(a, "_design", None) is not None:
        return a._design
    from arvcas.system.params import load
    from arvcas.sim import scenario

    params = load(a.system)
    design = {"controller": a.controller, "gains": None, "gains_source": None}
    cfg_text = None
    if a.front is not None:
        from arvcas.tuning import checkpoint as ck
        from arvcas.tuning.front import check_provenance, member_index, read_front, resolve_front_path, system_params

        path = resolve_front_path(a.front)
        if a.system is None:  # the front's own system
            params = system_params(ck.read_checkpoint(path))
        changed = check_provenance(path, params, a.allow_model_change, "--front")
        fr = read_front(path)
        i = member_index(fr, a.member)
        if a.controller is not None and a.controller != fr.controller:
            raise ValueError(f"--controller {a.controller} differs from the front's controller {fr.controller}")
        what = "its knee" if a.member == "knee" else "members sorted by f_chat"
        design.update(controller=fr.controller, gains=fr.gains[i].copy(), gains_source=(
            f"member {i} of the {fr.size} of the front {path} ({what}; {fr.describe(i, '.6g')})"
            + (f"; exported under another model than the study's ({changed}), as allowed by --allow-model-change"
               if changed else "")))
        cfg_text = (fr.scenario_text, f"{path} (study scenario)")
    if a.config is not None:
        cfg = scenario.load_scenario(a.config)
    elif cfg_text is not None and cfg_text[0]:
        cfg = scenario.loads_scenario(*cfg_text)
    elif params.default("scenario") is not None:
        cfg = scenario.load_scenario(params.default("scenario"))
    else:
        cfg = None  # export_controller names what is missing
    design.update(system=params, cfg=cfg)
    a._design = design
    return design


def _export_controller_outputs(a: argparse.Namespace) -> list:
    from arvcas.export.controller import default_prefix, files

    d = _export_controller_design(a)
    if a.format == "ardusub-params":
        from arvcas.io.ardusub_params import default_name

        return [(f"DIR {a.dir}", a.dir / default_name(d["system"].structure.name), "export-controller", a.dir)]
    return [(f"DIR {a.dir}", a.dir / n, "export-controller", a.dir)
            for n in files(a.prefix or default_prefix(d["system"], d["controller"]))]


def _run_export_controller(a: argparse.Namespace) -> int:
    from arvcas.export.controller import export_controller

    d = _export_controller_design(a)
    if a.format == "ardusub-params":
        return _run_export_ardusub_params(a, d)
    paths = export_controller(a.dir, d["controller"], gains=d["gains"], system=d["system"], scenario=d["cfg"],
                              prefix=a.prefix, gains_source=d["gains_source"], force=a.force)
    for path in paths:
        print(path)
    if d["gains"] is not None:
        print(f"gains: {d['gains_source']}")
    print(f"build with: make -C {a.dir}")
    return 0


# ---- export-fmu --------------------------------------------------------------------------------


def _add_export_fmu(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="FILE.fmu", type=Path, help="output file (name ending in .fmu)")
    p.add_argument("--inputs", choices=("wrench", "thrusters"), default="wrench",
                   help="first inputs: the body wrench tau at the COB in {b} (six, default) or the system's thruster "
                        "commands u (one per thruster)")
    add_model_args(p)


def _run_export_fmu(a: argparse.Namespace) -> int:
    from arvcas.build.fmu import export_fmu

    print(export_fmu(a.file, system=a.system, opts=model_options(a.n_quad), force=a.force, inputs=a.inputs))
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

def demo_table(params_path: Path | None = None, n_quad: int = 5, t_end: float = 25.0, dt: float = 1.0):
    """Coupling wrench tau_m (N, N m; in {b} about the COB) along the arm motion of the system's default
    scenario (Haidou-1's: from the stowed pose [90, 90, -90, 0, 90, 0] deg to qg = [60, 60, -60, 0, 60, 0] deg
    by a quintic over 5..20 s). The vehicle is at rest and level, payload 0. Returns rows (t, Fx..Mz).
    """
    import casadi as ca
    import numpy as np

    from arvcas.build.dynamics import compiled
    from arvcas.model.manipulator import stow_pose
    from arvcas.sim import limits, profiles, scenario
    from arvcas.system.params import load, view

    params = load(params_path)
    if params.structure.n_joints == 0:
        raise ValueError(f"demo: system '{params.structure.name}' ({params.path}) has no arm: there is no coupling "
                         f"wrench to show")
    p = params.vector()
    if params.default("scenario") is None:
        raise ValueError(f"demo: system '{params.structure.name}' ({params.path}) names no default scenario "
                         f"([defaults] scenario): the demo follows its arm motion")
    cfg = scenario.load_scenario(params.default("scenario"))
    limits.check_joint_limits(cfg, params)
    f = compiled("arm_wrench", model_options(n_quad), system=params)
    z6 = np.zeros(6)
    ts = ca.SX.sym("t")
    fq = ca.Function("q", [ts], list(profiles.joint_trajectory(cfg, stow_pose(view(p, params.layout)), ts)))
    traj = lambda t: [np.array(x).ravel() for x in fq(t)]  # noqa: E731
    rows = []
    for k in range(int(round(t_end / dt)) + 1):
        t = k * dt
        q, qd, qdd = traj(t)
        tau_m = np.asarray(f(z6, z6, z6, q, qd, qdd, 0.0, p)).ravel()
        rows.append((t, *tau_m))
    return rows


def _add_demo(p: argparse.ArgumentParser) -> None:
    add_model_args(p)


def _run_demo(a: argparse.Namespace) -> int:
    from arvcas.system.params import load

    rows = demo_table(a.system, a.n_quad)
    params = load(a.system)
    print("coupling wrench tau_m of the arm on the vehicle ({b}, about the COB), vehicle at rest and level,")
    print(f"{params.structure.name}: the arm motion of its default scenario ({params.default('scenario').name}), "
          f"payload 0")
    cols = ("t [s]", "Fx [N]", "Fy [N]", "Fz [N]", "Mx [N m]", "My [N m]", "Mz [N m]")
    print("".join(f"{c:>12}" for c in cols))
    for r in rows:
        print(f"{r[0]:12.1f}" + "".join(f"{v:12.4f}" for v in r[1:]))
    return 0


# ---- systems -----------------------------------------------------------------------------------


def _add_systems(p: argparse.ArgumentParser) -> None:
    pass


def _run_systems(a: argparse.Namespace) -> int:
    from arvcas.system import load_system, shipped

    print(f"{'name':24} {'thrusters':>9} {'joints':>6} {'arm':>6} {'params':>6}  description")
    for name in shipped():
        s = load_system(name)
        print(f"{name:24} {s.n_thrusters:9d} {s.n_joints:6d} {s.structure.arm:>6} {len(s.params):6d}  {s.description}")
        print(f"{'':24} {s.path}")
    return 0


def _add_params(p: argparse.ArgumentParser) -> None:
    add_system_arg(p, type=str)
    p.add_argument("--match", default=None, metavar="TEXT",
                   help="only the parameters whose name contains TEXT (e.g. hydro. or thrusters.T1.)")


def _run_params(a: argparse.Namespace) -> int:
    """Every parameter of a system: the name (what identify --free, Params.replace and the compiled ``p``
    take), its value in SI, the SI unit and the file's source of the number."""
    from arvcas.build.units import si_unit
    from arvcas.system import load_system

    s = load_system(a.system)
    P = s.params
    names = [n for n in P.names() if a.match is None or a.match in n]
    if not names:
        from arvcas.system.config import closest

        raise ValueError(f"--match: no parameter of {s.name} contains {a.match!r}{closest(a.match, P.names())}")
    print(f"# {len(names)} of {len(P)} parameters of {s.name} ({s.path}): the names identify --free takes; "
          f"values in SI")
    w = max(len(n) for n in names)
    for n in names:
        print(f"{n:{w}}  {P[n]:>14.8g}  {si_unit(P, n):12}  {P.source(n)}")
    return 0


# ---- import-system -------------------------------------------------------------------------------


def _numbers(n: int | None, what: str):
    """An argparse type: comma-separated finite numbers (``n`` of them, or any number >= 1)."""
    def parse(text: str) -> list[float]:
        try:
            v = [float(x) for x in text.split(",")]
        except ValueError:
            v = []
        if not v or (n is not None and len(v) != n) or not all(math.isfinite(x) for x in v):
            raise argparse.ArgumentTypeError(f"{what}: expected {n or 'one or more'} comma-separated numbers, "
                                             f"got {text!r}")
        return v

    return parse


def _lock_arg(text: str) -> tuple[str, float]:
    name, eq, value = text.rpartition("=")
    try:
        q = float(value)
    except ValueError:
        q = math.nan
    if not eq or not name or not math.isfinite(q):
        raise argparse.ArgumentTypeError(f"--lock: expected JOINT=POSITION (rad, or m for a prismatic joint), "
                                         f"got {text!r}")
    return name, q


def _add_import_uuv(p: argparse.ArgumentParser) -> None:
    p.add_argument("description", type=Path, metavar="DESCRIPTION",
                   help="the robot's URDF or xacro file, or its description package's folder (its robots/ file "
                        "named *default*)")
    p.add_argument("--out", type=Path, required=True, metavar="FILE.toml", help="the system file to write")
    p.add_argument("--name", default=None, help="the system's name (default: the URDF's robot name)")
    p.add_argument("--base-link", default=None, metavar="LINK", help="the vehicle's link (default: the URDF's root)")
    p.add_argument("--arm-base", default=None, metavar="LINK",
                   help="import the arm from this link (rigid on the vehicle; its weight and buoyancy join the "
                        "vehicle's) ...")
    p.add_argument("--tool-link", default=None, metavar="LINK", help="... to this link (the chain's end)")
    p.add_argument("--tool-offset", type=_numbers(3, "--tool-offset"), default=None, metavar="X,Y,Z",
                   help="the tool point in --tool-link's frame, m (default: its origin)")
    p.add_argument("--lock", action="append", type=_lock_arg, default=None, metavar="JOINT=POSITION",
                   help="hold a joint at a position (rad; m for a prismatic joint), e.g. a gripper's finger; "
                        "repeat for each")
    p.add_argument("--stow", type=_numbers(None, "--stow"), default=None, metavar="Q1,Q2,...",
                   help="the arm's stow pose, rad (default: its zero pose, clipped to the limits)")
    p.add_argument("--thruster-manager", type=Path, default=None, metavar="YAML",
                   help="uuv_simulator's thruster_manager.yaml: its max_thrust is the thrust limit")
    p.add_argument("--max-thrust", type=float, default=None, metavar="N",
                   help="the thrust limit, N (when the thruster plugins give no thrustMin/thrustMax)")
    p.add_argument("--gravity", type=float, default=None, metavar="M_PER_S2",
                   help="the world's gravity (default 9.8, SDF's default, which uuv_simulator's worlds keep)")
    p.add_argument("--ros-path", action="append", type=Path, default=None, metavar="DIR",
                   help="a folder holding ROS packages for $(find ...) (default: the folder holding the "
                        "description's package); repeatable")
    p.add_argument("--xacro-arg", action="append", default=None, metavar="NAME:=VALUE", help="a xacro argument")
    p.add_argument("--check-tam", type=Path, default=None, metavar="TAM.yaml",
                   help="compare the written system's allocation matrix with uuv_simulator's TAM.yaml after the "
                        "frame change and print the largest difference")
    p.add_argument("--cite", default="", metavar="TEXT",
                   help="put before every source, e.g. the repository and commit of the description")


def _check_import_uuv(a: argparse.Namespace) -> None:
    from arvcas.system.uuv import check_options

    check_options(a.arm_base, a.tool_link, a.tool_offset, a.stow, a.max_thrust, a.thruster_manager, a.gravity,
                  ValueError)


def _run_import_uuv(a: argparse.Namespace) -> int:
    import tempfile

    import numpy as np

    from arvcas.util import files
    from arvcas.system import params as params_mod
    from arvcas.system import uuv

    args = {}
    for x in a.xacro_arg or []:
        k, sep, v = x.partition(":=")
        if not sep or not k:
            raise ValueError(f"--xacro-arg: expected NAME:=VALUE, got {x!r}")
        args[k] = v
    tam = uuv.read_tam(a.check_tam, ValueError) if a.check_tam is not None else None
    imp = uuv.import_uuv(a.description, name=a.name, base_link=a.base_link, arm_base=a.arm_base,
                         tool_link=a.tool_link, tool_offset=a.tool_offset,
                         locks={k: (v, f"--lock {k}") for k, v in a.lock or []}, stow=a.stow,
                         max_thrust=a.max_thrust, thruster_manager=a.thruster_manager, gravity=a.gravity,
                         ros_paths=a.ros_path or (), xacro_args=args, cite=a.cite, error=ValueError)
    with tempfile.TemporaryDirectory() as d:  # the file must load before it is written
        tmp = Path(d) / a.out.name
        tmp.write_text(imp.text, encoding="utf-8")
        try:
            params = params_mod.load(tmp)
        except ValueError as e:
            raise ValueError(f"the imported system does not load (arvcas's fault, please report): "
                             f"{str(e).replace(str(tmp), str(a.out))}") from None
    files.write_text(a.out, imp.text)
    print(f"{a.out}: system '{imp.name}', {params.structure.n_thrusters} thrusters, {params.structure.n_joints} "
          f"joints, {len(params)} parameters")
    for n in imp.notes:
        print(f"  not imported: {n}")
    if tam is not None:
        from arvcas.model.thrusters import B_T

        if tam.shape[1] != imp.B_flu.shape[1]:
            raise ValueError(f"--check-tam {a.check_tam}: {tam.shape[1]} columns, the description has "
                             f"{imp.B_flu.shape[1]} thrusters")
        T6 = np.kron(np.eye(2), uuv.T_FLU_FRD)
        B = np.array(B_T(params_mod.view(params.vector(), params.layout)), dtype=float)
        print(f"allocation matrix against {a.check_tam} (columns {', '.join(imp.thrusters)}; the TAM turned into "
              f"x forward, y starboard, z down): largest difference {np.abs(B - T6 @ tam).max():.3g}")
    return 0


# ---- controllers -------------------------------------------------------------------------------


def _add_controllers(p: argparse.ArgumentParser) -> None:
    pass


def _run_controllers(a: argparse.Namespace) -> int:
    from arvcas.controllers import base

    names, failed = base.available()  # every entry point of arvcas.controllers loaded; broken ones reported
    print(f"{'name':16} {'gains/DOF':>9}  {'from':40}  description")
    for n in names:
        c = base.get(n)
        p = base.origin(n)
        own = c.own_source_files()
        where = p.describe() if p is not None else (f"python: {type(c).__module__}" if own else "arvcas")
        print(f"{n:16} {len(c.gains):9d}  {where:40}  {c.description}")
    als = base.aliases()
    if als:
        print("aliases (accepted wherever a controller is named; files keep the name): "
              + ", ".join(f"{k} = {v}" for k, v in als.items()))
    for f in failed:
        print(f"warning: {f}", file=sys.stderr)
    return 0


# ---- bench -------------------------------------------------------------------------------------


def _add_bench(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quick", action="store_true", help="tiny repetition counts, no opt-level sweep (CI check)")
    p.add_argument("--out", type=Path, default=Path("results"), metavar="DIR",
                   help="where bench.json and bench.md go (default: results/)")
    p.add_argument("--wait-load", type=_load_arg, default=None, metavar="L",
                   help="first wait (up to 15 min) until the 1-min load average is at most L")
    p.add_argument("--only", default="", metavar="S1,S2",
                   help="measure only these sections (plant, closed_loop, targets, compile, startup, systems, "
                        "identification, controller, lanes, cost) into the existing bench.json in --out "
                        "(cost: also its figures and README in --out/cost/)")


def _load_arg(text: str) -> float:
    """A 1-minute load average to wait for: finite and >= 0 (a load average is never negative)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a load average, got {text!r}") from None
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(f"{text}: a load average is a finite number >= 0")
    return v


def bench_module():
    """The benchmark package :mod:`arvcas.bench` (imported on demand: it is the top of every layer)."""
    import importlib

    return importlib.import_module("arvcas.bench")


def _run_bench(a: argparse.Namespace) -> int:
    from arvcas.util import files

    files.prepare_dir(a.out, f"--out {a.out}")  # before measuring
    run = bench_module().run
    run(a.out, quick=a.quick, wait_load=a.wait_load, only=tuple(k for k in a.only.split(",") if k))
    print(f"wrote {a.out / 'bench.json'} and {a.out / 'bench.md'}")
    return 0


# ---- declared outputs -------------------------------------------------------------------------------------


def _bench_outputs(a):
    return [(f"--out {a.out}", a.out / n) for n in ("bench.json", "bench.md")]


def _table() -> tuple[Command, ...]:
    from arvcas.experiments import cli as x
    from arvcas.experiments import validation as v
    from arvcas.tuning import cli as t

    return (
        Command("export-c", "write the plant functions as a C library with Makefile, example and README",
                _add_export_c, _run_export_c, inputs=(("system", "system"),), outputs=_export_c_outputs),
        Command("export-controller", "write the controller of a run (EKF, reference, law, allocation) with a front "
                "member's or the default gains as a C library with header, Makefile, ctypes binding and examples",
                _add_export_controller, _run_export_controller,
                inputs=(("config", "file"), ("system", "system"), ("front", "front")),
                outputs=_export_controller_outputs, check=_check_export_controller, plugins=True),
        Command("export-fmu", "write an FMI 2.0 FMU (Model Exchange and Co-Simulation) of the coupled vehicle + arm",
                _add_export_fmu, _run_export_fmu, inputs=(("system", "system"),), outputs=out_file("file", "FILE.fmu")),
        Command("cache", "show the build cache directory and its compiled libraries", _add_cache, _run_cache),
        Command("params", "list every parameter of a system: name (what identify --free takes), SI value, unit, "
                          "source", _add_params, _run_params),
        Command("systems", "list the shipped systems (vehicle, thrusters, arm) and their files", _add_systems,
                _run_systems),
        Command("import-system uuv", "a uuv_simulator / Gazebo vehicle (URDF or xacro, the Fossen plugin, thrusters, "
                "an arm) as a system file, in arvcas's body frame (docs/importing.md)", _add_import_uuv,
                _run_import_uuv, inputs=(("description", "description", "robot description"),
                                         ("thruster_manager", "file"), ("check_tam", "file")),
                outputs=out_file("out"), check=_check_import_uuv),
        Command("controllers", "list the controllers: the package's, the plugins' (entry points, --plugin) and "
                "where each comes from", _add_controllers, _run_controllers, plugins=True),
        Command("knees", "replay the knee of every front of a study directory: result files, figures, a table",
                x.add_knees, x.run_knees, inputs=(("study_dir", "front", "study directory"),), outputs=x.knees_outputs,
                plugins=True),
        Command("demo", "print the arm's coupling wrench on the vehicle along a simple arm motion",
                _add_demo, _run_demo, inputs=(("system", "system"),)),
        Command("simulate", "run the station-keeping experiment once and print CHAT/RMSE per DOF",
                x.add_simulate, x.run_simulate, inputs=(("config", "file"), ("system", "system"), ("from_front", "front")),
                outputs=out_file("out", **RESULT_FORMATS), check=x.check_simulate, plugins=True),
        Command("paper", "the paper's experiment end to end: three controllers, Table 3, Figures 5-11",
                x.add_paper, x.run_paper, outputs=x.paper_outputs),
        Command("bench", "measure plant, closed-loop and compile speed; write bench.json and bench.md",
                _add_bench, _run_bench, outputs=_bench_outputs),
        Command("tune", "NSGA-II on the CHAT/RMSE front from a study file (resumable, local or Dask)",
                t.add_tune, t.run_tune, inputs=(("study", "file", "study file"),), check=t.check_tune, plugins=True),
        Command("front export", "the front as CSV or JSON (stdout, or --out FILE), or a MATLAB .mat file",
                t.add_front_export, t.run_front_export, inputs=(("file", "front"),), outputs=out_file("out", mat="arvcas-front"),
                check=t.check_front_export),
        Command("front plot", "plot the front, the default gains (Haidou-1: Table 2) on the same draws and the knee "
                "point (PNG, PDF or SVG)", t.add_front_plot,
                t.run_front_plot, inputs=(("file", "front"),), outputs=t.front_plot_outputs),
        Command("front restamp", "replay every member of a front on today's code; if all reproduce bit for bit, "
                "record today's run digest so the front stays valid (--check: report only)", t.add_front_restamp,
                t.run_front_restamp, inputs=(("fronts", "front"),), plugins=True),
        Command("front explore", "one self-contained HTML page of every front: hover a member for its gains and "
                "metrics, click it for its time response", x.add_explore, x.run_explore, inputs=(("fronts", "front"),),
                outputs=x.explore_outputs, check=x.check_explore, plugins=True),
        Command("front robust", "re-evaluate every front member under Monte Carlo; mark the robust non-dominated "
                "ones (robust.h5, robust.md, robust.png)", x.add_robust, x.run_robust, inputs=(("file", "front"),),
                outputs=x.robust_outputs, check=x.check_robust, plugins=True),
        Command("compare", "hypervolumes of two or more fronts against one reference point, and who dominates where; "
                "or two Monte Carlo files (per-DOF differences with 95 percent intervals); or two robust fronts "
                "(front robust)", x.add_compare, x.run_compare, inputs=(("fronts", "front"),),
                outputs=x.compare_outputs, check=x.check_compare, plugins=True),
        Command("sweep", "every controller at several controller sampling periods: CHAT, RMSE, zigzag of k1 "
                "(table, plot)", x.add_sweep, x.run_sweep,
                inputs=(("config", "file"), ("system", "system"), ("check", "file")),
                outputs=x.sweep_outputs, check=x.check_sweep, plugins=True),
        Command("validate", "simulate a system open loop and k steps ahead over logged trials (*.log.toml) and "
                "compare: RMSE, NRMSE, R^2, FIT percent, residual tests per signal", v.add_validate, v.run_validate,
                inputs=(("system", "system"),), outputs=v.validate_outputs, check=v.check_validate),
        Command("identify", "estimate named parameters of a system from logged trials (IPOPT, 95 percent "
                "intervals): writes the identified system file", v.add_identify, v.run_identify,
                inputs=(("system", "system"),), outputs=v.identify_outputs, check=v.check_identify),
        Command("montecarlo", "Monte Carlo over noise seeds, nominal-model factors (+-30 percent) and disturbance "
                "phases: CIs, failure rate", x.add_montecarlo, x.run_montecarlo,
                inputs=(("config", "file"), ("system", "system"), ("from_front", "front"), ("check", "file")),
                outputs=x.montecarlo_outputs, check=x.check_montecarlo, plugins=True),
    )


TABLE: tuple[Command, ...] = _table()
_GROUPS = {"front": "tuning fronts", "import-system": "another tool's description as a system file"}
COMMANDS: dict[str, Command] = {c.name: c for c in TABLE}


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line (``arvcas: error: CMD: ...``), exit code 2."""

    def error(self, message):
        cmd = self.prog.partition(" ")[2]
        where = f"{cmd}: " if cmd else ""
        self.exit(2, f"arvcas: error: {where}{' '.join(message.split())} (see {self.prog} --help)\n")


def _parser() -> argparse.ArgumentParser:
    from arvcas._version import __version__

    ap = _Parser(prog="arvcas", description="Haidou-1 ARV + manipulator: CasADi models compiled to C")
    ap.add_argument("--version", action="version", version=f"arvcas {__version__}")
    ap.add_argument("-v", "--verbose", action="store_true", help="log progress (compiles, cache hits)")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_Parser)
    groups: dict[str, argparse._SubParsersAction] = {}
    for cmd in TABLE:
        head, _, action = cmd.name.partition(" ")
        if action:
            if head not in groups:
                actions = [c.name.partition(" ")[2] for c in TABLE if c.name.startswith(head + " ")]
                hp = f"{_GROUPS.get(head, head)}: {', '.join(actions)}"
                gp = sub.add_parser(head, help=hp, description=hp)
                groups[head] = gp.add_subparsers(dest="action", metavar="ACTION", required=True, parser_class=_Parser)
            sp = groups[head].add_parser(action, help=cmd.help, description=cmd.help)
        else:
            sp = sub.add_parser(head, help=cmd.help, description=cmd.help)
        cmd.add_arguments(sp)
        if cmd.plugins:
            sp.add_argument("--plugin", action="append", default=None, metavar="MODULE|FILE.py",
                            help="load a plugin first: a Python file or an importable module defining controllers "
                                 "or objectives (repeatable; installed entry points of arvcas.controllers and "
                                 "arvcas.objectives are found by themselves; docs/plugins.md, docs/objectives.md)")
        if cmd.outputs is not None:
            sp.add_argument("--force", action="store_true",
                            help="replace existing output files that arvcas did not write")
        sp.set_defaults(_command=cmd.name)
    return ap


def _inputs(cmd: Command, a: argparse.Namespace) -> list[tuple[str, Path]]:
    """Apply the input policy to the declared inputs (an argument may hold a list); returns them as
    (label, path of the file)."""
    out = []
    for dest, kind, *what in cmd.inputs:
        value = getattr(a, dest, None)
        for p in value if isinstance(value, list) else [value]:
            item = _input(dest, kind, what, p, a)
            if item is not None:
                out.append(item)
    return out


def _input(dest: str, kind: str, what: list, p, a: argparse.Namespace) -> tuple[str, Path] | None:
    """The input policy for one input ``p`` of argument ``dest``: (label, path of the file) or None."""
    from arvcas.util import files

    if p is None:
        return None
    label = ("front" if dest == "fronts" else dest if dest in ("file", "study", "study_dir", "description")
             else f"--{dest.replace('_', '-')}")
    if kind == "system":
        from arvcas.system import shipped

        label = "--system"
        if str(p) in shipped():
            p = shipped()[str(p)]
            setattr(a, dest, p)
        elif not p.exists() and p.suffix.lower() != ".toml":
            from arvcas.system.config import closest

            raise ValueError(f"--system {p}: neither a shipped system ({', '.join(shipped())}) nor a system "
                             f"file{closest(str(p), shipped(), 0.3)}")
    p = files.check_input(p, what[0] if what else "file", allow_dir=kind in ("front", "description"))
    if kind == "front" and p.is_dir():
        p = p / "front.h5"
        if not p.exists():
            return None  # the handler names what the directory holds
        files.check_input(p)
    return label, p


def _load_plugins(a: argparse.Namespace) -> list[tuple[str, Path]]:
    """Load the ``--plugin`` of a command (before its check: the check may look a controller up); returns
    the plugin files as inputs (no output may replace them)."""
    from arvcas.util import plugins

    out = []
    for spec in getattr(a, "plugin", None) or []:
        p = plugins.load(spec, what="--plugin")
        if p.kind == "file":
            out.append(("--plugin", Path(p.spec)))
    return out


def _canonical_controllers(a: argparse.Namespace) -> None:
    """A law named by an alias (``agsta_reso_decay`` for ``proposed``, ...) is given its registered name, once,
    before the command's check: what a command writes and compares names the law by that name."""
    from arvcas.controllers.base import canonical

    for k in ("controller", "controllers"):
        v = getattr(a, k, None)
        if isinstance(v, str):
            setattr(a, k, canonical(v))
        elif isinstance(v, list):
            setattr(a, k, [canonical(x) for x in v])


def _apply_policies(cmd: Command, a: argparse.Namespace) -> None:
    from arvcas.util import files

    inputs = _inputs(cmd, a) + _load_plugins(a)
    _canonical_controllers(a)
    if cmd.check is not None:
        cmd.check(a)
    if cmd.outputs is not None:
        outs = cmd.outputs(a)
        files.check_outputs(outs, inputs, force=a.force)
        for d in {o[1].parent if str(o[1].parent) else Path(".") for o in outs}:
            if d.is_dir():
                files.remove_stale_temps(d)


def _choose_numpy_mode() -> int | None:
    """CasADi 3.8's NumPy mode (CasADi's issue #2959) for this command: -1, the legacy behaviour without its notice.
    arvcas's own code calls no NumPy function on a CasADi value, so its numbers are the same in every mode
    (tests/test_trust_casadi_mode.py); -1 also keeps the libraries the commands use (pymoo, matplotlib)
    on the behaviour they were tested with. The previous mode is returned, to be restored (a caller in the
    same process keeps its own)."""
    import casadi as ca

    get = getattr(ca.GlobalOptions, "getNumpyMode", None)
    if get is None:  # pragma: no cover - CasADi before 3.8
        return None
    before = get()
    ca.GlobalOptions.setNumpyMode(-1)
    return before


def _restore_numpy_mode(before: int | None) -> None:
    if before is not None:
        import casadi as ca

        ca.GlobalOptions.setNumpyMode(before)


def main(argv: list[str] | None = None) -> int:
    """Run the ``arvcas`` command line; returns the exit code (0 ok, 2 usage or library error)."""
    import signal

    from arvcas.util import files

    ap = _parser()
    try:
        a = ap.parse_args(argv)
    except SystemExit as e:  # --help, --version, usage errors: argparse has printed the message
        return e.code if isinstance(e.code, int) else 2
    if a.verbose:
        import logging

        logging.basicConfig(level=logging.INFO, format="arvcas: %(message)s")
    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)}
    files.install_signal_handlers()
    import warnings

    shown = warnings.showwarning

    def show(message, category, *args, **kw):  # a system file's implausible number: one line
        if category.__name__ in ("PlausibilityWarning", "ScenarioWarning"):
            print(f"arvcas: warning: {' '.join(str(message).split())}", file=sys.stderr)
        else:
            shown(message, category, *args, **kw)

    warnings.showwarning = show
    numpy_mode = _choose_numpy_mode()
    try:
        from arvcas.build.codegen import report_progress

        cmd = COMMANDS[a._command]
        _apply_policies(cmd, a)
        from arvcas.sim.scenario import ScenarioWarning
        from arvcas.system.params import PlausibilityWarning

        # every invocation shows its files' warnings, even where the same text was shown earlier in this process
        with warnings.catch_warnings(), report_progress(sys.stderr):  # a long build says so on standard error
            warnings.showwarning = show
            for w in (PlausibilityWarning, ScenarioWarning):
                warnings.simplefilter("always", w)
            rc = cmd.run(a)
            files.check_signals()  # a signal whose exception was swallowed on the way (files.raise_for_signal)
            return rc
    except (ValueError, OSError) as e:
        msg = " ".join(str(e).split()) or type(e).__name__
        print(f"arvcas: error: {msg}", file=sys.stderr)
        return 2
    except files.Terminated as e:
        print(f"arvcas: terminated ({e})", file=sys.stderr)
        return 128 + e.signum
    except KeyboardInterrupt:
        print("arvcas: interrupted", file=sys.stderr)
        return 130
    finally:
        import threading

        warnings.showwarning = shown
        _restore_numpy_mode(numpy_mode)
        if threading.current_thread() is threading.main_thread():
            for s, h in old.items():
                if h is not None:
                    signal.signal(s, h)
            files.forget_signals()  # reported (or this command ended before its signal's handler ran)


if __name__ == "__main__":
    sys.exit(main())
