"""The result of an identification (:func:`arvcas.ident.identify.identify`): the estimates, their intervals,
the report with its flags, and the identified system file.

* :class:`Estimate`: values, Fisher standard errors (and, after :func:`arvcas.ident.identify.jackknife`, the
  leave-one-trial-out estimates), correlation, what the data could not identify, the solver's end;
  :meth:`Estimate.report` the table a user reads, :meth:`Estimate.flags` every estimate that ended at the edge
  of its physical set or moved more than :data:`MOVE_FACTOR` times its source value;
* :meth:`Estimate.system_text`: the system file with the estimates (the original text, comments kept, each
  free entry's value and ``source`` replaced), :func:`writable` (the free parameters the file itself holds),
  :func:`identified_name`;
* :meth:`Estimate.summary`: the numbers of the report as plain JSON types (``arvcas identify --json``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from arvcas.ident.solver import STALL_ITER

__all__ = ["IdentifyError", "Estimate", "writable", "identified_name", "t95", "CORR_WARN", "Z95", "MOVE_FACTOR"]

CORR_WARN = 0.95
Z95 = 1.959963984540054  # the normal distribution's 97.5 % point
MOVE_FACTOR = 3.0  # an estimate more than this many times (or less than 1 / this) its source value is flagged


def t95(dof: int) -> float:
    """The two-sided 95 % point of Student's t with ``dof`` degrees of freedom."""
    from scipy.stats import t

    return float(t.ppf(0.975, dof))


class IdentifyError(ValueError):
    """One line naming the argument or parameter at fault."""


@dataclass(frozen=True)
class Estimate:
    """The result of :func:`arvcas.ident.identify.identify`: values, intervals, what the data could not identify."""

    system: object
    free: tuple[str, ...]
    initial: np.ndarray
    values: np.ndarray
    std: np.ndarray  # one standard deviation (nan where unidentifiable)
    correlation: np.ndarray
    identifiable: np.ndarray  # bool per parameter
    unidentifiable: tuple[str, ...]  # one line per direction
    correlated: tuple[tuple[str, str, float], ...]
    trials: tuple[str, ...]
    signals: tuple[str, ...]
    sigma: dict[str, float]
    x0: dict[str, np.ndarray]
    cost0: float
    cost: float
    s2: float  # weighted residual sum of squares / degrees of freedom
    n_residuals: int
    status: str
    iterations: int
    seconds: float
    h: float
    at_bound: tuple[str, ...] = ()
    history: tuple[float, ...] = field(default=(), repr=False)
    rms0: dict = field(default_factory=dict)  # unweighted RMS error per fitted signal, at the start
    rms: dict = field(default_factory=dict)  # and at the estimate
    stated: tuple[str, ...] = ()  # the signals whose noise the logs state (the others are estimated)
    groups: tuple[str, ...] = ()  # the physical parameterisations used (arvcas.ident.physical)
    pulled: tuple | None = None  # (fraction of the last step kept, the loader's rule it broke) or None
    nonfinite: int = 0  # objective evaluations whose simulation was not finite
    inf_du: float = math.nan  # IPOPT's dual infeasibility at its last iteration
    max_iter: int = 0
    cost_kind: str = "simulation"  # the cost minimised (COSTS)
    horizon: int | None = None  # the prediction error's k (samples)
    dt: float = math.nan  # the logs' sample time (s)
    jackknife: dict | None = None  # leave-one-trial-out: trial -> estimates (jackknife_intervals)

    @property
    def cost_text(self) -> str:
        """The cost minimised, in words."""
        if self.cost_kind == "prediction":
            return (f"{self.horizon}-step-ahead prediction error ({self.horizon * self.dt:g} s: "
                    f"each trial cut into segments of {self.horizon} samples, each restarted from the logged state)")
        return "simulation error (open loop over each whole trial, its initial state free)"

    @property
    def jackknife_std(self) -> np.ndarray | None:
        """The leave-one-trial-out standard error per parameter, ``sqrt((T-1)/T sum (theta_(-j) - mean)^2)``."""
        if not self.jackknife:
            return None
        v = np.array(list(self.jackknife.values()))
        T = len(v)
        return np.sqrt((T - 1) / T * np.sum((v - v.mean(axis=0)) ** 2, axis=0))

    @property
    def jackknife_intervals(self) -> np.ndarray | None:
        """(n, 2) 95 % intervals ``estimate +- t_(T-1) sd_jackknife`` (Student's t with T - 1 degrees of freedom:
        T trials are T draws of everything a trial varies in); None without :func:`arvcas.ident.identify.jackknife`."""
        sd = self.jackknife_std
        if sd is None:
            return None
        q = t95(len(self.jackknife) - 1)
        return np.stack([self.values - q * sd, self.values + q * sd], axis=1)

    def flags(self) -> list[tuple[str, str]]:
        """(parameter, what it usually means) for every estimate at a bound, at the edge of its physical set,
        moved more than :data:`MOVE_FACTOR` times from its source value, or changed in sign."""
        out = []
        for k, n in enumerate(self.free):
            a, b = float(self.initial[k]), float(self.values[k])
            if n in self.at_bound:
                out.append((n, f"ended at the edge of its physical set ({b:.6g}): the data push it past what is "
                               f"physical, usually because it absorbs an effect the model lacks (a drift, a "
                               f"tether, a wrong number elsewhere); do not read it as measured"))
            if a != 0 and b != 0 and (a > 0) != (b > 0):
                out.append((n, f"changed sign ({a:.6g} -> {b:.6g}): check the model's sign convention, or what "
                               f"the parameter absorbs"))
            elif a != 0 and b != 0 and max(abs(b / a), abs(a / b)) > MOVE_FACTOR:
                out.append((n, f"moved {abs(b / a):.3g} times its source value ({a:.6g} -> {b:.6g}, more than "
                               f"{MOVE_FACTOR:g} times): a parameter that moves this far usually absorbs "
                               f"something the model lacks (e.g. heave damping soaking up a depth drift); compare "
                               f"fits on subsets of trials and validate on held-out ones"))
        return out

    @property
    def intervals(self) -> np.ndarray:
        """(n, 2) 95 % intervals (Gauss-Newton, normal approximation); nan where unidentifiable."""
        return np.stack([self.values - Z95 * self.std, self.values + Z95 * self.std], axis=1)

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.free, map(float, self.values)))

    def params(self):
        """The system's :class:`arvcas.system.params.Params` with the estimates."""
        return self.system.params.replace(self.as_dict())

    def system_text(self, out_path, date: str | None = None) -> str:
        """The system file with the estimates: the original file's text (comments kept, by ``tomlkit``) with
        each free entry's value replaced (in the file's own unit) and its ``source`` naming the trials, the
        date and the 95 % interval; ``[system] name`` gets ``_identified``; relative paths to other files
        (``[defaults]``, a URDF) are rewritten for ``out_path``'s folder. Everything else is unchanged."""
        return _system_text(self, out_path, date)

    def summary(self) -> dict:
        """The numbers of :meth:`report` as plain JSON types (``arvcas identify --json``): per parameter its
        initial value, estimate, standard error, Fisher 95 % interval (None where unidentifiable) and
        leave-one-trial-out interval (None without :func:`arvcas.ident.identify.jackknife`), unit, whether it
        ended at a bound and its flags; and the fit's cost, signals, trials, solver's end and RMS errors."""
        def num(x):
            return float(x) if math.isfinite(x) else None

        jk = self.jackknife_intervals
        why = {}
        for n, text in self.flags():
            why.setdefault(n, []).append(text)
        params = {}
        for k, n in enumerate(self.free):
            ok = bool(self.identifiable[k])
            params[n] = {"initial": float(self.initial[k]), "estimate": float(self.values[k]),
                         "std": num(self.std[k]) if ok else None,
                         "fisher": [float(v) for v in self.intervals[k]] if ok else None,
                         "jackknife": None if jk is None else [float(v) for v in jk[k]],
                         "unit": self.system.params.unit(n), "at_bound": n in self.at_bound, "flags": why.get(n, [])}
        return {"system": self.system.name, "trials": list(self.trials), "signals": list(self.signals),
                "cost": self.cost_kind, "horizon": self.horizon, "parameters": params,
                "unidentifiable": list(self.unidentifiable),
                "correlated": [[a, b, float(r)] for a, b, r in self.correlated],
                "status": self.status, "iterations": self.iterations, "seconds": self.seconds,
                "cost_start": num(self.cost0), "cost_end": num(self.cost), "s2": num(self.s2),
                "rms_start": {k: num(v) for k, v in self.rms0.items()}, "rms": {k: num(v) for k, v in self.rms.items()},
                "leave_out": None if not self.jackknife else {k: [float(x) for x in v]
                                                              for k, v in self.jackknife.items()}}

    def report(self) -> str:
        units = [self.system.params.unit(n) for n in self.free]
        rows = [f"identification of {len(self.free)} parameters of {self.system.name} on {len(self.trials)} trials "
                f"({', '.join(self.trials)}); signals {', '.join(self.signals)}; plant step {self.h:g} s",
                f"cost minimised: {self.cost_text}",
                f"IPOPT: {self.status}, {self.iterations} iterations, {self.seconds:.1f} s; cost "
                f"{self.cost0:.6g} -> {self.cost:.6g}; residual variance factor s^2 = {self.s2:.4g} "
                f"({self.n_residuals} residuals)"]
        rows += [f"physical parameterisation: {g}" for g in self.groups]
        rows += self._solver_notes()
        jk = self.jackknife_intervals
        rows += ["", f"{'parameter':28s} {'initial':>12s} {'estimate':>12s} {'95 % interval (Fisher)':>27s}" +
                 (f" {'95 % (leave-one-trial-out)':>27s}" if jk is not None else "") + "  unit"]
        flagged = {n for n, _ in self.flags()}
        for k, (n, a, b, s, ok, u) in enumerate(zip(self.free, self.initial, self.values, self.std, self.identifiable,
                                                    units)):
            iv = f"[{_num(b - Z95 * s, s)}, {_num(b + Z95 * s, s)}]" if ok else "not identifiable"
            iv = f"{iv:>27s}"
            if jk is not None:
                w = (jk[k, 1] - jk[k, 0]) / 2
                iv += f" {'[' + _num(jk[k, 0], w) + ', ' + _num(jk[k, 1], w) + ']':>27s}"
            flag = "  (at its bound)" if n in self.at_bound else "  (flagged)" if n in flagged else ""
            rows.append(f"{n:28s} {a:12.5g} {b:12.5g} {iv}  {u}{flag}")
        rows += ["", "The Fisher intervals assume errors independent from sample to sample; where the model cannot",
                 "follow the vehicle (errors that persist over seconds), they are too narrow."]
        if jk is not None:
            rows += [f"The leave-one-trial-out (jackknife) intervals come from {len(self.jackknife)} refits, each "
                     f"without one trial:", "they carry the trial-to-trial spread and errors correlated within a "
                     "trial (docs/identification.md)."]
        else:
            rows += ["For intervals that carry them, --intervals jackknife (at least 3 trials); validate on held-out "
                     "trials."]
        if self.flags():
            rows += ["", "flags:"] + [f"  {n}: {why}" for n, why in self.flags()]
        if self.unidentifiable:
            rows += ["", "directions the data do not determine:"] + [f"  {u}" for u in self.unidentifiable]
        if self.correlated:
            rows += ["", f"strongly correlated (|r| > {CORR_WARN}):"] + \
                    [f"  {a} ~ {b}: r = {r:+.3f}" for a, b, r in self.correlated]
        return "\n".join(rows)

    def _solver_notes(self) -> list[str]:
        """What the solver's end means: the iteration cap with the optimality measure and what to try, the
        count of non-finite evaluations, the hold inside the loader's rules."""
        rows = []
        if self.status == "Maximum_Iterations_Exceeded":
            h = [v for v in self.history if math.isfinite(v)][-STALL_ITER - 1:]
            rows.append(f"stopped at the iteration cap ({self.max_iter}) before converging: IPOPT's dual "
                        f"infeasibility (its optimality measure, 0 at an optimum) is {self.inf_du:.3g}, the "
                        f"objective changed by {max(h) - min(h) if h else math.nan:.3g} over the last "
                        f"{len(h) - 1} iterations; try more iterations (--max-iter), fewer free parameters "
                        f"(those named below as unidentifiable or correlated), or starting values nearer the "
                        f"data (a previous estimate as the system file)")
        elif self.status not in ("interrupted", "Solve_Succeeded", "Solved_To_Acceptable_Level",
                                 "User_Requested_Stop") and not self.status.startswith("converged"):
            rows.append(f"IPOPT ended with {self.status} (dual infeasibility {self.inf_du:.3g}): the estimate is "
                        f"the best iterate, not an optimum; try fewer free parameters or better starting values")
        if self.nonfinite:
            rows.append(f"{self.nonfinite} evaluations of the simulation were not finite (NaN or inf; counted, not "
                        f"printed): IPOPT tried parameters at which the model diverges on a trial and stepped "
                        f"back; harmless when the fit converged, otherwise the starting values or the free set "
                        f"let the model go unstable")
        if self.pulled is not None:
            frac, why = self.pulled
            rows.append(f"the optimiser's last point broke a rule of the system file ({why}); the estimate is "
                        f"held at {100 * frac:.3g} % of the way from the start to it, on the edge of what loads: "
                        f"its values are bounded there, not fitted")
        return rows


def _num(x: float, width: float) -> str:
    """``x`` with enough digits to show a difference of ``width``."""
    if not (math.isfinite(x) and math.isfinite(width)) or width <= 0 or x == 0:
        return f"{x:.5g}"
    d = max(4, int(math.ceil(math.log10(abs(x) / width))) + 2)
    return f"{x:.{min(d, 15)}g}"


# ---- the identified system file ---------------------------------------------------------------------------


def _locate(doc, leaf: str):
    """The tomlkit table holding ``leaf`` (a parameter's file key) and the key within it."""
    parts = leaf.split(".")
    node = doc
    if parts[0] == "thrusters" and "unit" in doc.get("thrusters", {}):
        node = next(u for u in doc["thrusters"]["unit"] if u["name"] == parts[1])
        parts = parts[2:]
        return node, parts[0]
    for k in parts[:-1]:
        node = node[k]
    return node, parts[-1]


def writable(system, names) -> None:
    """Refuse (one line) free parameters the system file does not write itself: a URDF arm's joints,
    inertials and tool come from the URDF, which arvcas does not rewrite."""
    import tomllib

    from arvcas.util.files import read_text

    doc = tomllib.loads(read_text(system.path, "system file", IdentifyError))
    maps = doc.get("thrusters", {}).get("map", {}) if isinstance(doc.get("thrusters"), dict) else {}
    for n in names:
        parts = n.split(".")
        if n.startswith("thrusters.map.") and isinstance(maps.get(parts[2]), dict) and "table" in maps[parts[2]]:
            raise IdentifyError(f"free: {n} comes from the thrust table file {maps[parts[2]]['table']!r}, which "
                                f"arvcas does not rewrite: write the map's points in the system file "
                                f"(command = {{...}}, thrust = {{...}}, docs/system-file.md) to identify them")
    arm = doc.get("arm", {})
    if not (isinstance(arm, dict) and "urdf" in arm):
        return
    in_toml = (".volume", ".cob", ".drag_diameter", ".drag_from", ".drag_to", ".Cd")
    for n in names:
        if n.startswith(("arm.joint", "arm.tool")) or (n.startswith("arm.link") and not any(k in n for k in in_toml)):
            raise IdentifyError(f"free: {n} comes from the URDF file {arm['urdf']!r}, which arvcas does not rewrite: "
                                f"identify it in a chain-form system file (docs/system-file.md)")


def _si_factor(unit: str, k: int) -> float:
    from arvcas.system import config

    units = [u.strip() for u in unit.split(",")]
    u = units[k] if len(units) > 1 else units[0]
    if u == config.SI:
        return 1.0
    return config.UNITS[u][1]


def identified_name(name: str) -> str:
    """``<name>_identified`` within the loader's rule for names (at most 64 characters: the old name is
    shortened to make room); a name that already ends in ``_identified`` is kept."""
    from arvcas.system.systemfile import NAME_RE

    suffix = "_identified"
    if name.endswith(suffix) and NAME_RE.match(name):
        return name
    out = name[: 64 - len(suffix)] + suffix
    assert NAME_RE.match(out), out
    return out


def _system_text(est: Estimate, out_path, date: str | None) -> str:
    import datetime
    import os
    from pathlib import Path

    import tomlkit

    from arvcas.system.systemfile import VECTOR_ELEMENTS

    src = Path(est.system.path)
    from arvcas.util.files import read_text

    doc = tomlkit.parse(read_text(src, "system file", IdentifyError))
    date = date or datetime.date.today().isoformat()
    lay = est.system.layout
    trials = ", ".join(est.trials)
    for k, name in enumerate(est.free):
        leaf = lay.leaf[lay.index[name]]
        table, key = _locate(doc, leaf)
        entry = table[key]
        unit = str(entry.get("unit", "SI"))
        old_src = str(entry.get("source", ""))
        if leaf == name:
            el = 0
            f = _si_factor(unit, 0)
            old = float(entry["value"]) * f
            entry["value"] = float(f"{est.values[k] / f:.10g}")
        else:
            el = VECTOR_ELEMENTS[leaf.rsplit(".", 1)[-1]].index(name.rsplit(".", 1)[-1])
            f = _si_factor(unit, el)
            old = float(entry["value"][el]) * f
            entry["value"][el] = float(f"{est.values[k] / f:.10g}")
        if est.identifiable[k]:
            lo, hi = (est.values[k] - Z95 * est.std[k]) / f, (est.values[k] + Z95 * est.std[k]) / f
            w = Z95 * est.std[k] / f
            what = f"95 % interval [{_num(lo, w)}, {_num(hi, w)}] {unit} (Gauss-Newton, s^2 = {est.s2:.3g})"
        else:
            what = "not identifiable from these trials alone (a combination is; see the report): value of the joint fit"
        jk = est.jackknife_intervals
        if jk is not None:
            w = (jk[k, 1] - jk[k, 0]) / 2 / f
            what += f"; leave-one-trial-out 95 % interval [{_num(jk[k, 0] / f, w)}, {_num(jk[k, 1] / f, w)}] {unit}"
        what += f"; cost: {est.cost_kind}" + (f", horizon {est.horizon} samples" if est.horizon else "")
        entry["source"] = (f"identified by arvcas identify on {date} from trials {trials} ({what}); "
                           f"was {old / f:.6g} {unit}: {old_src}")
    sysname = str(doc["system"]["name"]) if "system" in doc and "name" in doc["system"] else est.system.name
    if "system" not in doc:
        doc.add("system", tomlkit.table())
    doc["system"]["name"] = identified_name(sysname)
    desc = str(doc["system"].get("description", est.system.description))
    doc["system"]["description"] = f"{desc} (identified from {len(est.trials)} trials, {date})"
    out_dir = Path(out_path).resolve().parent

    def moved(rel: str) -> str:
        p = Path(rel)
        if p.is_absolute():
            return rel
        return Path(os.path.relpath((src.parent / p).resolve(), out_dir)).as_posix()

    for k in list(doc.get("defaults", {}).keys()):
        doc["defaults"][k] = moved(str(doc["defaults"][k]))
    if isinstance(doc.get("arm"), dict) and "urdf" in doc["arm"]:
        doc["arm"]["urdf"] = moved(str(doc["arm"]["urdf"]))
    maps = doc.get("thrusters", {}).get("map", {}) if isinstance(doc.get("thrusters"), dict) else {}
    for m in maps.values():  # a table beside the old file (a shipped table's bare name is found anywhere)
        if isinstance(m, dict) and isinstance(m.get("table"), str) and (src.parent / m["table"]).exists():
            m["table"] = moved(m["table"])
    head = (f"# Identified by arvcas identify on {date} from {src.name} and trials {trials}: parameters "
            f"{', '.join(est.free)} estimated (docs/identification.md) by minimising the {est.cost_text}; every "
            f"other number is {src.name}'s.\n")
    return head + tomlkit.dumps(doc)
