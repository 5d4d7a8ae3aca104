"""``arvcas validate`` and ``arvcas identify``: a system against real trials, and its parameters from them.

``validate`` writes, for every trial, the open-loop simulation and the k-step-ahead prediction against
what the vehicle did (:mod:`arvcas.ident.validate`): ``DIR/validation.json`` (metrics, FIT % and residual
tests per trial and signal, SI units: m, rad, m/s, rad/s; a summary per role), ``DIR/README.md`` (the
tables, angles in degrees) and, with ``--figures``, ``DIR/<trial>.png`` (measured, simulated and predicted
signals). A trial's role is ``fit`` when the system's parameters were identified on it (their sources name
the trials ``arvcas identify`` used, or ``--fitted``), else ``held out``. ``identify`` writes the identified system file
(:mod:`arvcas.ident.identify`), its report as the file's header comment, and prints progress per IPOPT
iteration; Ctrl-C keeps the best iterate.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from pathlib import Path

import numpy as np

from arvcas.io import style
from arvcas.io.cliargs import add_figure_format

__all__ = ["add_validate", "run_validate", "validate_outputs", "check_validate", "fitted_trials", "summary",
           "summary_lines", "add_identify", "run_identify", "identify_outputs",
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
    from arvcas.ident.logcache import load_logs  # parsed once, then from the cache (arvcas.ident.logcache)
    from arvcas.ident.plant import check_log

    logs = load_logs(a.logs, system.n_joints, tuple(system.structure.thrusters or ()))
    for lg in logs:  # joints, thrusters and commands against the system, before any work
        check_log(lg, system)
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


DEFAULT_K = 25  # samples: the k-step-ahead predictor's default horizon (0.5 s at 50 Hz)


def _k_arg(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of samples, got {text!r}") from None
    if not 1 <= v <= 1_000_000:
        raise argparse.ArgumentTypeError(f"the prediction horizon must be in [1, 1000000] samples, got {text}")
    return v


def add_validate(p: argparse.ArgumentParser) -> None:
    _add_common(p, "", "DIR", "output directory")
    p.add_argument("--k", type=_k_arg, default=DEFAULT_K, metavar="N",
                   help=f"horizon of the k-step-ahead prediction, in log samples (default {DEFAULT_K}; the state is "
                        "restarted from the log every N samples, as MATLAB's compare(data, sys, N))")
    p.add_argument("--fitted", type=_names, default=None, metavar="TRIAL,...",
                   help="the trials the system was fitted on (default: those its parameters' sources name)")
    p.add_argument("--figures", action="store_true", help="also draw a figure per trial (slow: about 1-3 s each)")
    add_figure_format(p, "the trials' figures (with --figures)")


def validate_outputs(a) -> list:
    names = [_trial_name(p) for p in a.logs]
    out = [("--out", a.out / "validation.json"), ("--out", a.out / "README.md")]
    if not getattr(a, "figures", False):
        return out
    return out + [("--out", a.out / f"{n}.{a.format or 'png'}") for n in names]


def check_validate(a) -> None:
    if a.format is not None and not a.figures:
        raise ValueError(f"--format {a.format}: figures are drawn only with --figures")


def _trial_name(p: Path) -> str:
    """The trial's name before the file is read: the mapping's [log] name is checked against it on load."""
    from arvcas.ident.logs import MAPPING_SUFFIX

    return p.name[: -len(MAPPING_SUFFIX)] if p.name.endswith(MAPPING_SUFFIX) else p.stem


_FITTED = re.compile(r"identified by arvcas identify on \S+ from trials (.+?) \(")


def fitted_trials(system) -> set[str]:
    """The trials a system file's parameters were identified on: those their sources name (``arvcas identify``
    writes ``identified by arvcas identify on DATE from trials A, B (...)``); empty for a sourced system."""
    out: set[str] = set()
    for n in system.params.names():
        m = _FITTED.search(system.params.source(n) or "")
        if m:
            out.update(t.strip() for t in m.group(1).split(","))
    return out


def _roles(results, fitted) -> dict[str, str]:
    return {r.name: ("fit" if r.name in fitted else "held out") for r in results}


ROLES = ("fit", "held out")
_SUMMARY_KEYS = ("rmse", "fit", "kstep_rmse", "kstep_fit", "auto_outside", "cross_outside")


def summary(results, roles: dict[str, str]) -> dict:
    """Per role and vehicle signal, over the trials of that role: the median RMSE and FIT % of the open-loop
    simulation and of the k-step-ahead prediction, and the median fractions of lags outside the residual
    tests' 99 % band (the cross-correlation's: the largest over the inputs)."""
    out: dict = {}
    for role in ROLES:
        rs = [r for r in results if roles[r.name] == role]
        if not rs:
            continue
        sigs = [s for s in UNITS if any(s in r.resid for r in rs)]
        ent = {"trials": [r.name for r in rs], "signals": {}}
        for s in sigs:
            vals: dict[str, list[float]] = {k: [] for k in _SUMMARY_KEYS}
            for r in rs:
                if s not in r.metrics["rmse"]:
                    continue
                vals["rmse"].append(r.metrics["rmse"][s])
                vals["fit"].append(r.metrics["fit"][s])
                if r.kstep:
                    vals["kstep_rmse"].append(r.kstep["rmse"][s])
                    vals["kstep_fit"].append(r.kstep["fit"][s])
                t = r.resid.get(s)
                if t:
                    vals["auto_outside"].append(t["auto_outside"])
                    vals["cross_outside"].append(max(t["cross_outside"].values(), default=0.0))
            ent["signals"][s] = {k: (float(np.median(v)) if v else None) for k, v in vals.items()}
        out[role] = ent
    return out


def validation_doc(system, results, logs, h_max, roles: dict[str, str] | None = None) -> dict:
    """The ``validation.json`` document: ``{"system", "trials": {name: {"rmse", "nrmse", "r2", "max_error", "fit",
    "kstep", "resid", "role", ...}}, "summary": {role: ...}}``."""
    from arvcas.ident import validate as V

    roles = roles or {r.name: "held out" for r in results}
    trials = {}
    for r, lg in zip(results, logs):
        trials[r.name] = {
            "role": roles[r.name],
            "rmse": r.metrics["rmse"], "nrmse": r.metrics["nrmse"], "r2": r.metrics["r2"],
            "max_error": r.metrics["max_error"], "fit": r.metrics["fit"],
            "kstep": None if r.k is None else {"k": r.k, **r.kstep},
            "resid": r.resid,
            "log": _shown(lg.path), "duration_s": lg.duration, "samples": len(lg.t), "plant_step_s": r.h,
            "simulation_finite": r.ok, "x0": [float(v) for v in r.x0],
            "joint_cutoff_hz": None if lg.joints is None else lg.joints.cutoff,
        }
    return {"format": "arvcas-validation-2", "system": system.name, "system_file": _shown(system.path),
            "units": {s: _unit(s) for r in results for s in r.metrics["rmse"]},
            "definitions": {"rmse": "root mean square of simulated - measured on the log's time base",
                            "nrmse": "rmse / (max - min of the measured signal)",
                            "r2": "1 - sum(e^2) / sum((y - mean(y))^2)", "max_error": "max |simulated - measured|",
                            "fit": "100 (1 - ||y - y_hat|| / ||y - mean(y)||), 2-norms (MATLAB compare's FIT %)",
                            "kstep": "the same metrics of the k-step-ahead prediction: the state restarted from the "
                                     "log every k samples (k in samples; sample j predicted (j - 1) mod k + 1 ahead)",
                            "resid": f"residual e = measured - simulated (open loop), means removed: normalised "
                                     f"autocorrelation at lags 1..{V.RESID_LAGS} and cross-correlation with each "
                                     f"logged input at lags -{V.RESID_LAGS}..{V.RESID_LAGS}; band = {V.RESID_Z} / "
                                     f"sqrt(N) (99 %, MATLAB resid); *_outside: fraction of those lags outside it",
                            "role": "fit: the system's parameters were identified on this trial; held out: not"},
            "h_max_s": h_max, "summary": summary(results, roles), "trials": trials}


def _deg(s: str) -> float:
    return 180.0 / math.pi if _unit(s) in ("rad", "rad/s") else 1.0


def _shown_unit(s: str) -> str:
    return {"rad": "deg", "rad/s": "deg/s"}.get(_unit(s), _unit(s))


def summary_lines(doc: dict, markdown: bool) -> list[str]:
    """The per-role summary of a ``validation.json`` document as text: a Markdown table or console lines."""
    k = next((t["kstep"]["k"] for t in doc["trials"].values() if t.get("kstep")), None)
    head = ["role", "signal", "trials", "RMSE (sim)", f"RMSE ({k}-step)", "FIT % (sim)", f"FIT % ({k}-step)",
            "resid auto out", "resid cross out"]
    rows = []
    for role, ent in doc["summary"].items():
        for s, v in ent["signals"].items():
            f = _deg(s)

            def num(x, fmt, scale=1.0):
                return "-" if x is None else format(scale * x, fmt)

            rows.append([role, s, str(len(ent["trials"])), f"{num(v['rmse'], '.3g', f)} {_shown_unit(s)}",
                         f"{num(v['kstep_rmse'], '.3g', f)} {_shown_unit(s)}", num(v["fit"], ".1f"),
                         num(v["kstep_fit"], ".1f"), num(v["auto_outside"], ".0%"), num(v["cross_outside"], ".0%")])
    if markdown:
        return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(r) + " |" for r in rows]
    w = [max(len(x) for x in col) for col in zip(head, *rows)]
    return ["  ".join(x.ljust(n) for x, n in zip(r, w)).rstrip() for r in [head, *rows]]


@style.styled
def plot_trial(r, title: str):
    """Measured (solid), simulated (dashed) and k-step-ahead predicted (dotted) signals of one trial; angles
    in degrees (the house style)."""
    sigs = [s for s in ("roll", "pitch", "yaw", "z", "p", "q", "r", "x", "y", "u", "v", "w") if s in r.measured]
    joints = [s for s in r.measured if s not in UNITS]
    n = len(sigs) + (1 if joints else 0)
    cols = 2
    rows = -(-n // cols)
    fig = style.figure("page", 1.5 * rows + 0.4)
    axs = fig.subplots(rows, cols, sharex=True, squeeze=False).reshape(-1)
    for ax, s in zip(axs, sigs):
        k = _deg(s)
        u = _shown_unit(s)
        ax.plot(r.t, k * r.measured[s], color=style.color("blue"), label="measured")
        ax.plot(r.t, k * r.simulated[s], ls="--", color=style.color("vermillion"), label="simulated")
        if s in r.predicted:
            ax.plot(r.t, k * r.predicted[s], ls=":", color=style.color("green"), label=f"{r.k}-step ahead")
        ax.set_ylabel(f"{s} ({u})")
        rm = r.metrics["rmse"][s] * k
        ax.set_title(f"{s}: RMSE {rm:.3g} {u}, FIT {r.metrics['fit'][s]:.0f} %")
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


def _readme(doc: dict, results, logs, system, seconds: float, fmt: str | None) -> str:
    k = next((r.k for r in results if r.k is not None), None)
    lines = [f"# Validation of `{system.name}` on {len(results)} trials",
             "", f"Written by `arvcas validate`: each trial simulated open loop from its logged initial state, "
             f"driven by the logged inputs, over the whole trial (simulation error), and predicted {k} samples ahead "
             f"(the state restarted from the log every {k} samples, as MATLAB's `compare(data, sys, {k})`). System "
             f"file: `{_shown(system.path)}`. Metrics in `validation.json` (SI); here angles and rates in degrees. "
             f"{seconds:.2f} s for all trials (without figures).", "",
             "## Summary per role and signal (medians over the trials)", "",
             "FIT % as the MATLAB System Identification Toolbox: 100 (1 - ||y - y_hat|| / ||y - mean y||). The "
             "residual tests (MATLAB `resid`) are of the open-loop residual: the fraction of lags whose normalised "
             "autocorrelation (lags 1-25) or cross-correlation with a logged input (lags -25-25, the worst input) is "
             "outside the 99 % band +-2.58/sqrt(N); about 1 % for a residual the model explains. A trial is `fit` "
             "when the system's parameters were identified on it.", "", *summary_lines(doc, True), "",
             "## Per trial", "",
             "| trial | role | s | roll RMSE (deg) | pitch RMSE (deg) | yaw RMSE (deg) | z RMSE (m) | "
             "p, q, r RMSE (deg/s) | roll / pitch FIT % | roll / pitch FIT %, k-step |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r, lg in zip(results, logs):
        m = r.metrics["rmse"]

        def deg(s):
            return f"{math.degrees(m[s]):.2f}" if s in m else "-"

        rates = ", ".join(f"{math.degrees(m[s]):.2f}" for s in ("p", "q", "r") if s in m) or "-"
        fit = " / ".join(f"{r.metrics['fit'][s]:.1f}" for s in ("roll", "pitch") if s in m) or "-"
        kfit = " / ".join(f"{r.kstep['fit'][s]:.1f}" for s in ("roll", "pitch") if r.kstep and s in m) or "-"
        z = f"{m['z']:.3f}" if "z" in m else "-"
        lines.append(f"| {r.name} | {doc['trials'][r.name]['role']} | {lg.duration:.1f} | {deg('roll')} | "
                     f"{deg('pitch')} | {deg('yaw')} | {z} | {rates} | {fit} | {kfit} |")
    lines.append("")
    if fmt:
        lines += ["Figures: " + ", ".join(f"[{r.name}]({r.name}.{fmt})" for r in results), ""]
    joints = [lg for lg in logs if lg.joints is not None]
    if joints:
        lines.append(f"The joints follow the logged trajectory (smoothing splines that halve amplitudes at "
                     f"{joints[0].joints.cutoff:g} Hz); their error in `validation.json` is the smoothing's against "
                     f"the raw samples, not a model error.")
    return "\n".join(lines) + "\n"


def run_validate(a) -> int:
    from arvcas.ident.validate import validate_log
    from arvcas.util import files

    system = _system(a)
    logs = _logs(a, system)
    for p, lg in zip(a.logs, logs):
        if lg.name != _trial_name(p):
            raise ValueError(f"{p}: [log] name {lg.name!r} differs from the file's name {_trial_name(p)!r}: "
                             f"the output figure is named by the file")
    unknown = sorted(set(a.fitted or ()) - {lg.name for lg in logs})
    if unknown:
        raise ValueError(f"--fitted: no trial named {unknown[0]!r} among the logs given "
                         f"({', '.join(lg.name for lg in logs)})")
    files.prepare_dir(a.out, "--out")
    t0 = time.perf_counter()
    results = []
    for lg in logs:
        h = lg.dt if a.h_max is None else a.h_max
        r = validate_log(system, lg, h_max=h, k=a.k)
        results.append(r)
        m = r.metrics["rmse"]
        rp = ", ".join(f"{s} {math.degrees(m[s]):.2f} deg (FIT {r.metrics['fit'][s]:.0f} %)"
                       for s in ("roll", "pitch") if s in m)
        print(f"{lg.name}: {lg.duration:.1f} s, RMSE {rp}{'' if r.ok else ' (simulation not finite)'}")
    seconds = time.perf_counter() - t0
    fitted = set(a.fitted) if a.fitted is not None else fitted_trials(system)
    doc = validation_doc(system, results, logs, a.h_max, _roles(results, fitted))
    print("\n".join(summary_lines(doc, False)))
    files.write_text(a.out / "validation.json", json.dumps(doc, indent=1, allow_nan=True) + "\n")
    fmt = (a.format or "png") if a.figures else None
    if fmt:
        for r in results:
            style.write_figure(a.out / f"{r.name}.{fmt}", plot_trial(r, f"{system.name}: trial {r.name}"))
    files.write_text(a.out / "README.md", _readme(doc, results, logs, system, seconds, fmt))
    print(f"wrote {_shown(a.out / 'validation.json')}, README.md" + (f" and {len(results)} figures" if fmt else ""))
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
    p.add_argument("--cost", default="simulation", metavar="simulation|prediction",
                   help="the cost minimised: simulation error (open loop over each trial, default) or the k-step-ahead "
                        "prediction error (each trial restarted from the log every --horizon samples)")
    p.add_argument("--horizon", type=int, default=None, metavar="K",
                   help="the prediction error's horizon in samples (with --cost prediction)")
    p.add_argument("--intervals", default="fisher", metavar="fisher|jackknife",
                   help="fisher (default); jackknife: also leave-one-trial-out intervals, one refit per trial "
                        "(at least 3 trials)")
    p.add_argument("--json", type=Path, default=None, metavar="FILE.json",
                   help="also write the report's numbers (per parameter: estimate, intervals, flags) as JSON")


def identify_outputs(a) -> list:
    return [("--out", a.out)] + ([("--json", a.json)] if a.json is not None else [])


def check_identify(a) -> None:
    if not 1 <= a.max_iter <= 10_000:
        raise ValueError(f"--max-iter: must be in [1, 10000], got {a.max_iter}")
    if not 1 <= a.threads <= 256:
        raise ValueError(f"--threads: must be in [1, 256], got {a.threads}")
    if a.out.suffix.lower() != ".toml":
        raise ValueError(f"--out {a.out}: the identified system file must end in .toml")
    from arvcas.ident.identify import IdentifyError, check_cost

    try:
        check_cost(a.cost, a.horizon)
    except IdentifyError as e:
        raise ValueError(f"--{e}") from None
    if a.intervals not in ("fisher", "jackknife"):
        raise ValueError(f"--intervals: expected fisher or jackknife, got {a.intervals!r}")
    if a.json is not None and a.json.suffix.lower() != ".json":
        raise ValueError(f"--json {a.json}: the file must end in .json")
    if a.intervals == "jackknife" and len(a.logs) < 3:
        raise ValueError(f"--intervals jackknife: leave-one-trial-out needs at least 3 trials, got {len(a.logs)}")


def _check_loads(out: Path, text: str) -> None:
    """Load ``text`` as the system file ``out`` would be (a temporary beside it, removed): one line and nothing
    written if the loader refuses it."""
    import os

    from arvcas.util import files
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
    from arvcas.ident.estimate import writable
    from arvcas.ident.identify import identify
    from arvcas.util import files

    system = _system(a)
    for n in a.free:
        if n not in system.layout.index:
            from arvcas.system.config import closest

            head, _, last = n.rpartition(".")  # thrusters.T1.z: thrusters.T1.position.z
            near = [x for x in system.layout.names if x.startswith(head + ".") and x.endswith("." + last)]
            hint = (f" (did you mean {' or '.join(repr(x) for x in near[:3])}?)" if near
                    else closest(n, system.layout.names))
            from arvcas.system import shipped

            which = system.name if shipped().get(system.name) == Path(system.path) else system.path
            raise ValueError(f"--free: {system.name} has no parameter {n!r}{hint}; `arvcas params --system "
                             f"{which}` lists them")
    writable(system, a.free)
    logs = _logs(a, system)
    h = a.h_max if a.h_max is not None else logs[0].dt

    def progress(k, f):
        print(f"iteration {k:3d}: cost {f:.8g}", flush=True)

    print(f"identifying {len(a.free)} parameters of {system.name} on {len(logs)} trials ...", flush=True)
    kw = {"h_max": h, "max_iter": a.max_iter, "threads": a.threads}
    est = identify(system, logs, a.free, signals=a.signals, progress=progress, cost=a.cost, horizon=a.horizon, **kw)
    if a.intervals == "jackknife" and est.status != "interrupted":
        from arvcas.ident.identify import jackknife

        print(f"leave-one-trial-out: {len(logs)} refits, each without one trial ...", flush=True)
        est = jackknife(est, logs, progress=lambda name, sub: print(f"  without {name}: {sub.status}, "
                                                                     f"{sub.iterations} iterations", flush=True),
                        **kw)
    report = est.report()
    print(report)
    text = est.system_text(a.out)
    header = "".join(f"# {ln}\n" if ln else "#\n" for ln in report.splitlines())
    files.prepare_dir(a.out.parent if str(a.out.parent) else Path("."), "--out")
    _check_loads(a.out, header + "#\n" + text)
    files.write_text(a.out, header + "#\n" + text)
    print(f"wrote {a.out}" + (" (interrupted: the best iterate)" if est.status == "interrupted" else ""))
    if a.json is not None:
        files.prepare_dir(a.json.parent if str(a.json.parent) else Path("."), "--json")
        files.write_text(a.json, json.dumps(est.summary(), indent=1) + "\n")
        print(f"wrote {a.json}")
    return 0 if est.status != "interrupted" else 130
