"""``arvcas validate`` and ``arvcas identify``: a system against real trials, and its parameters from them.

``validate`` writes, for every trial, the open-loop simulation against what the vehicle did
(:mod:`arvcas.ident.validate`): ``DIR/validation.json`` (metrics per trial and signal, SI units: m, rad,
m/s, rad/s), ``DIR/<trial>.png`` (measured and simulated signals) and ``DIR/README.md`` (the table, roll
and pitch in degrees, the figures). ``identify`` writes the identified system file
(:mod:`arvcas.ident.identify`), its report as the file's header comment, and prints progress per IPOPT
iteration; Ctrl-C keeps the best iterate.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from arvcas.io import style
from arvcas.io.cliargs import add_figure_format

__all__ = ["add_validate", "run_validate", "validate_outputs", "add_identify", "run_identify", "identify_outputs",
           "validation_doc", "plot_trial", "UNITS"]

UNITS = {"x": "m", "y": "m", "z": "m", "roll": "rad", "pitch": "rad", "yaw": "rad", "u": "m/s", "v": "m/s",
         "w": "m/s", "p": "rad/s", "q": "rad/s", "r": "rad/s"}
_ANGLES = ("roll", "pitch", "yaw")


def _shown(path) -> str:
    """A path as a user would write it: relative to the working directory when it lies below it."""
    import os

    p = Path(path).resolve()
    try:
        return p.relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return os.fspath(path)


def _unit(sig: str) -> str:
    return UNITS.get(sig, "rad")  # joints: rad


def _system(a):
    from arvcas.system import load_system

    return load_system(a.system)


def _logs(a, system):
    from arvcas.ident.logs import load_logs
    from arvcas.ident.plant import check_commands

    logs = load_logs(a.logs, system.n_joints, tuple(system.structure.thrusters or ()))
    for lg in logs:  # thruster commands against the system's maps, before any work
        check_commands(lg, system)
    return logs


def _h_arg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a time step in s, got {text!r}") from None
    if not (math.isfinite(v) and 1e-4 <= v <= 1.0):
        raise argparse.ArgumentTypeError(f"the plant step must be in [1e-4, 1] s, got {text}")
    return v


# ---- validate --------------------------------------------------------------------------------------------


def _add_common(p: argparse.ArgumentParser, system_help: str, out_meta: str, out_help: str) -> None:
    p.add_argument("--system", required=True, type=Path, metavar="NAME|FILE",
                   help=f"a shipped system (arvcas systems) or a system file{system_help}")
    p.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="log mapping files (*.log.toml, docs/logs.md)")
    p.add_argument("--out", required=True, type=Path, metavar=out_meta, help=out_help)
    p.add_argument("--h-max", type=_h_arg, default=None, metavar="S",
                   help="largest plant RK4 step, s (default: the logs' sample time)")


def add_validate(p: argparse.ArgumentParser) -> None:
    _add_common(p, "", "DIR", "output directory")
    add_figure_format(p, "the trials' figures")


def validate_outputs(a) -> list:
    names = [_trial_name(p) for p in a.logs]
    out = [("--out", a.out / "validation.json"), ("--out", a.out / "README.md")]
    return out + [("--out", a.out / f"{n}.{a.format or 'png'}") for n in names]


def _trial_name(p: Path) -> str:
    """The trial's name before the file is read: the mapping's [log] name is checked against it on load."""
    from arvcas.ident.logs import MAPPING_SUFFIX

    return p.name[: -len(MAPPING_SUFFIX)] if p.name.endswith(MAPPING_SUFFIX) else p.stem


def validation_doc(system, results, logs, h_max) -> dict:
    """The ``validation.json`` document: ``{"system", "trials": {name: {"rmse", "nrmse", "r2", "max_error", ...}}}``."""
    trials = {}
    for r, lg in zip(results, logs):
        trials[r.name] = {
            "rmse": r.metrics["rmse"], "nrmse": r.metrics["nrmse"], "r2": r.metrics["r2"],
            "max_error": r.metrics["max_error"],
            "log": _shown(lg.path), "duration_s": lg.duration, "samples": len(lg.t), "plant_step_s": r.h,
            "simulation_finite": r.ok, "x0": [float(v) for v in r.x0],
            "joint_cutoff_hz": None if lg.joints is None else lg.joints.cutoff,
        }
    return {"format": "arvcas-validation-1", "system": system.name, "system_file": _shown(system.path),
            "units": {s: _unit(s) for r in results for s in r.metrics["rmse"]},
            "definitions": {"rmse": "root mean square of simulated - measured on the log's time base",
                            "nrmse": "rmse / (max - min of the measured signal)",
                            "r2": "1 - sum(e^2) / sum((y - mean(y))^2)", "max_error": "max |simulated - measured|"},
            "h_max_s": h_max, "trials": trials}


@style.styled
def plot_trial(r, title: str):
    """Measured (solid) and simulated (dashed) signals of one trial; angles in degrees (the house style)."""
    sigs = [s for s in ("roll", "pitch", "yaw", "z", "p", "q", "r", "x", "y", "u", "v", "w") if s in r.measured]
    joints = [s for s in r.measured if s not in UNITS]
    n = len(sigs) + (1 if joints else 0)
    cols = 2
    rows = -(-n // cols)
    fig = style.figure("page", 1.5 * rows + 0.4)
    axs = fig.subplots(rows, cols, sharex=True, squeeze=False).reshape(-1)
    for ax, s in zip(axs, sigs):
        k = 180.0 / math.pi if s in _ANGLES or s in ("p", "q", "r") else 1.0
        u = {"rad": "deg", "rad/s": "deg/s"}.get(_unit(s), _unit(s))
        ax.plot(r.t, k * r.measured[s], color=style.color("blue"), label="measured")
        ax.plot(r.t, k * r.simulated[s], ls="--", color=style.color("vermillion"), label="simulated")
        ax.set_ylabel(f"{s} ({u})")
        rm = r.metrics["rmse"][s] * k
        ax.set_title(f"{s}: RMSE {rm:.3g} {u}, R$^2$ {r.metrics['r2'][s]:.2f}")
    if joints:
        ax = axs[len(sigs)]
        for j in joints:
            ax.plot(r.t, np.degrees(r.measured[j]), label=f"{j}")
        ax.set_ylabel("joints (deg, prescribed)")
        ax.legend(ncol=len(joints))
    for ax in axs[n:]:
        ax.set_visible(False)
    axs[0].legend()
    for ax in axs[max(0, n - cols):n]:
        ax.set_xlabel("t (s)")
    fig.suptitle(title)
    return fig


def _readme(doc: dict, results, logs, system, seconds: float, fmt: str = "png") -> str:
    lines = [f"# Validation of `{system.name}` on {len(results)} trials",
             "", f"Written by `arvcas validate` ({time.strftime('%Y-%m-%d')}): each trial simulated open loop from its "
             f"logged initial state, driven by the logged inputs, over the whole trial (simulation error, not "
             f"one-step prediction). System file: `{_shown(system.path)}`. Metrics in `validation.json` (SI); here angles "
             f"and rates in degrees. {seconds:.1f} s for all trials.", "",
             "| trial | s | roll RMSE (deg) | pitch RMSE (deg) | yaw RMSE (deg) | z RMSE (m) | p, q, r RMSE (deg/s) | "
             "roll / pitch R^2 |", "|---|---|---|---|---|---|---|---|"]
    for r, lg in zip(results, logs):
        m = r.metrics["rmse"]

        def deg(s):
            return f"{math.degrees(m[s]):.2f}" if s in m else "-"

        rates = ", ".join(f"{math.degrees(m[s]):.2f}" for s in ("p", "q", "r") if s in m) or "-"
        r2 = " / ".join(f"{r.metrics['r2'][s]:.2f}" for s in ("roll", "pitch") if s in m) or "-"
        z = f"{m['z']:.3f}" if "z" in m else "-"
        lines.append(f"| {r.name} | {lg.duration:.1f} | {deg('roll')} | {deg('pitch')} | {deg('yaw')} | {z} | "
                     f"{rates} | {r2} |")
    lines += ["", "Figures: " + ", ".join(f"[{r.name}]({r.name}.{fmt})" for r in results), ""]
    joints = [lg for lg in logs if lg.joints is not None]
    if joints:
        lines.append(f"The joints follow the logged trajectory (smoothing splines that halve amplitudes at "
                     f"{joints[0].joints.cutoff:g} Hz); their error in `validation.json` is the smoothing's against "
                     f"the raw samples, not a model error.")
    return "\n".join(lines) + "\n"


def run_validate(a) -> int:
    from arvcas.ident.validate import validate_log
    from arvcas.io import files

    system = _system(a)
    logs = _logs(a, system)
    for p, lg in zip(a.logs, logs):
        if lg.name != _trial_name(p):
            raise ValueError(f"{p}: [log] name {lg.name!r} differs from the file's name {_trial_name(p)!r}: "
                             f"the output figure is named by the file")
    files.prepare_dir(a.out, "--out")
    t0 = time.perf_counter()
    results = []
    for lg in logs:
        h = lg.dt if a.h_max is None else a.h_max
        r = validate_log(system, lg, h_max=h)
        results.append(r)
        m = r.metrics["rmse"]
        rp = ", ".join(f"{s} {math.degrees(m[s]):.2f} deg" for s in ("roll", "pitch") if s in m)
        print(f"{lg.name}: {lg.duration:.1f} s, RMSE {rp}{'' if r.ok else ' (simulation not finite)'}")
    seconds = time.perf_counter() - t0
    doc = validation_doc(system, results, logs, a.h_max)
    files.write_text(a.out / "validation.json", json.dumps(doc, indent=1, allow_nan=True) + "\n")
    for r in results:
        style.write_figure(a.out / f"{r.name}.{a.format or 'png'}", plot_trial(r, f"{system.name}: trial {r.name}"))
    files.write_text(a.out / "README.md", _readme(doc, results, logs, system, seconds, a.format or "png"))
    print(f"wrote {a.out / 'validation.json'}, README.md and {len(results)} figures")
    return 0


# ---- identify --------------------------------------------------------------------------------------------


def _names(text: str) -> tuple[str, ...]:
    out = tuple(n.strip() for n in text.split(",") if n.strip())
    if not out:
        raise argparse.ArgumentTypeError("expected comma-separated names")
    return out


def add_identify(p: argparse.ArgumentParser) -> None:
    _add_common(p, ": the model and the starting values", "FILE.toml", "the identified system file")
    p.add_argument("--free", required=True, type=_names, metavar="NAME,...",
                   help="the parameters to estimate, by their names in the system (e.g. vehicle.zB,hydro.K_p)")
    p.add_argument("--signals", type=_names, default=None, metavar="NAME,...",
                   help="the measured signals to fit (default: every vehicle signal the logs give)")
    p.add_argument("--max-iter", type=int, default=100, metavar="N", help="IPOPT iterations (default 100)")
    p.add_argument("--threads", type=int, default=2, metavar="N", help="trials simulated at once (default 2)")


def identify_outputs(a) -> list:
    return [("--out", a.out)]


def check_identify(a) -> None:
    if not 1 <= a.max_iter <= 10_000:
        raise ValueError(f"--max-iter: must be in [1, 10000], got {a.max_iter}")
    if not 1 <= a.threads <= 256:
        raise ValueError(f"--threads: must be in [1, 256], got {a.threads}")
    if a.out.suffix.lower() != ".toml":
        raise ValueError(f"--out {a.out}: the identified system file must end in .toml")


def _check_loads(out: Path, text: str) -> None:
    """Load ``text`` as the system file ``out`` would be (a temporary beside it, removed): one line and nothing
    written if the loader refuses it."""
    import os

    from arvcas.io import files
    from arvcas.system import load_system

    tmp = out.parent / f".{out.stem}{files.TMP_MARK}{os.getpid()}-check.toml"
    try:
        tmp.write_text(text, encoding="utf-8")
        load_system(tmp)
    except ValueError as e:
        raise ValueError(f"--out {out}: the identified system would not load, so it is not written: "
                         f"{str(e).replace(str(tmp), str(out))}") from None
    finally:
        tmp.unlink(missing_ok=True)


def run_identify(a) -> int:
    from arvcas.ident.identify import identify, writable
    from arvcas.io import files

    system = _system(a)
    for n in a.free:
        if n not in system.layout.index:
            from arvcas.system.config import closest

            raise ValueError(f"--free: {system.name} has no parameter {n!r}{closest(n, system.layout.names)}")
    writable(system, a.free)
    logs = _logs(a, system)
    h = a.h_max if a.h_max is not None else logs[0].dt

    def progress(k, f):
        print(f"iteration {k:3d}: cost {f:.8g}", flush=True)

    print(f"identifying {len(a.free)} parameters of {system.name} on {len(logs)} trials ...", flush=True)
    est = identify(system, logs, a.free, signals=a.signals, h_max=h, max_iter=a.max_iter, threads=a.threads,
                   progress=progress)
    report = est.report()
    print(report)
    text = est.system_text(a.out)
    header = "".join(f"# {ln}\n" if ln else "#\n" for ln in report.splitlines())
    files.prepare_dir(a.out.parent if str(a.out.parent) else Path("."), "--out")
    _check_loads(a.out, header + "#\n" + text)
    files.write_text(a.out, header + "#\n" + text)
    print(f"wrote {a.out}" + (" (interrupted: the best iterate)" if est.status == "interrupted" else ""))
    return 0 if est.status != "interrupted" else 130
