"""Sampling-period sweep: every controller at several controller periods h, the plant unchanged.

The paper (section 4.3) claims that the traditional decreasing law's zigzag of k1 near k1min "will
only appear after the controller is discretized and becomes severe with the increase of sampling
time", while the proposed law "is not affected by the sampling time". :func:`run_sweep` runs each
controller with its Table 2 gains (continuous-time parameters, unchanged) at each ``h`` (sensors,
EKF, ATD, RESO and GSTA all sampled at ``h``; the plant's RK4 step stays the scenario's ``h_plant`` where it divides
``h``, else the largest step below it that does: :meth:`ScenarioConfig.with_h`) for
one or more noise seeds, and measures CHAT, RMSE and the zigzag of k1.

Zigzag of k1 (per DOF; laws with a k1min only: proposed, traditional, implicit), from the stored
series ``k1_k``, ``s_k`` at the samples ``k = 0..N`` and ``dk_k = k1_{k+1} - k1_k``:

- ``reversals``: samples ``k`` (1..N-1) where k1 changes direction, ``dk_{k-1} dk_k < 0``, while
  within one adaptation step of k1min, ``|k1_k - k1min| <= l h``. The traditional law, once at
  k1min with ``|s| <= sigma``, reverses every sample (up by ``l h`` below k1min, down above it).
- ``rises_inside``: samples ``k`` (0..N-1) where k1 rises (``dk_k > 0``) although ``|s_k| <= sigma``:
  an increase the sliding variable did not ask for. The proposed law has none by construction.
- ``amplitude``: mean ``|dk|`` over the reversal samples (0 without reversals), i.e. the size of one
  zigzag step; for the traditional law it is ``l h``.

Totals are sums over the six DOF. CHAT (eq. 42) is per controller sample, so at a longer ``h`` the
same slew rate gives a larger CHAT; ``CHAT / h`` (per second) is in the file as well.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from arvcas.controllers import gains as gains_mod
from arvcas.io import style
from arvcas.io.plots import controller_color
from arvcas.metrics import indices as metrics
from arvcas.sim import scenario
from arvcas.system.loader import UNSET, renamed_system
from arvcas.system.params import SCHEMA as PARAM_SCHEMA, Params, load as load_params
from arvcas.sim.scenario import ScenarioConfig
from arvcas.sim.simulation import simulate
from arvcas.experiments import _io

__all__ = ["Sweep", "zigzag", "zigzag_time_fraction", "run_sweep", "reproduce_sweep", "write_sweep", "read_sweep",
           "sweep_markdown", "plot_sweep", "write_sweep_dir", "CONTROLLERS", "FORMAT", "FORMAT_VERSION"]

CONTROLLERS = ("proposed", "traditional", "implicit", "agsta")
FORMAT = "arvcas-sweep"
FORMAT_VERSION = 1
DOFS = metrics.DOFS
_DOF_MD = ("x", "y", "z", "φ", "θ", "ψ")
_ZZ = ("reversals", "rises_inside", "amplitude")
_ARRAYS = ("chat", "rmse", "ok", "t_fail") + _ZZ


def zigzag(k1, s, controller: str, gains, h: float) -> dict[str, np.ndarray] | None:
    """Per-DOF zigzag measures of one run (module docstring); None for a law without k1min (agsta).

    Args:
        k1, s: (N+1, 6) series at the controller samples.
        controller, gains: the run's controller and flat gain vector (for k1min, l, sigma).
        h: controller sampling period, s.
    """
    g = gains_mod.unpack(controller, np.asarray(gains, dtype=float))
    if "k1min" not in g:
        return None
    kmin, step, sigma = (np.asarray(g[k], dtype=float) for k in ("k1min", "l", "sigma"))
    step = step * h
    k1, s = np.asarray(k1, dtype=float), np.asarray(s, dtype=float)
    dk = np.diff(k1, axis=0)
    rev = (dk[:-1] * dk[1:] < 0) & (np.abs(k1[1:-1] - kmin) <= step * (1 + 1e-9))
    rises = (dk > 0) & (np.abs(s[:-1]) <= sigma)
    n_rev = rev.sum(axis=0)
    amp = np.where(n_rev > 0, np.sum(np.abs(dk[1:]) * rev, axis=0) / np.maximum(n_rev, 1), 0.0)
    return {"reversals": n_rev.astype(float), "rises_inside": rises.sum(axis=0).astype(float), "amplitude": amp}


@dataclass
class Sweep:
    """Results of :func:`run_sweep`; arrays indexed [controller, h, seed, dof] (or without dof).

    ``k1_seed0[c][j]`` is the k1 series (N_j+1, 6) of controller ``c`` at ``hs[j]`` for the first seed
    (for the figure), ``t_seed0[j]`` its sample times.
    """

    hs: tuple[float, ...]
    controllers: tuple[str, ...]
    seeds: tuple[int, ...]
    gains: dict[str, np.ndarray]
    chat: np.ndarray
    rmse: np.ndarray
    ok: np.ndarray
    t_fail: np.ndarray
    reversals: np.ndarray
    rises_inside: np.ndarray
    amplitude: np.ndarray
    k1_seed0: dict[str, list[np.ndarray]]
    config_text: str
    params_vector: np.ndarray
    noise_scale: float = 1.0
    meta: dict = field(default_factory=dict)

    def objectives(self) -> np.ndarray:
        """docs/model.md §7 (f_chat, f_rmse), shape [controller, h, seed, 2]; NaN for diverged runs."""
        out = np.full(self.ok.shape + (2,), np.nan)
        ref = self.meta.get("reference")
        held = scenario.held_dofs(scenario.loads_scenario(self.config_text, "the sweep's scenario"))  # docs/sensors.md
        for idx in zip(*np.nonzero(self.ok)):
            out[idx] = metrics.normalised_objectives(self.chat[idx], self.rmse[idx], ref, held)
        return out


def _check_h(cfg: ScenarioConfig, h: float) -> ScenarioConfig:
    if not (isinstance(h, (int, float)) and math.isfinite(h) and h > 0):
        raise ValueError(f"--h: sampling periods must be positive numbers, got {h!r}")
    c = cfg.with_h(float(h))
    r = c.time_duration / c.time_h
    if abs(r - round(r)) > 1e-9:
        raise ValueError(f"--h {h:g}: the run length {c.time_duration:g} s is not a whole number of samples")
    return c


def run_sweep(hs: Sequence[float], controllers: Sequence[str] = CONTROLLERS, seeds: Sequence[int] = (0,),
              cfg: ScenarioConfig | None = None, system: Params | None = None, gains: dict | None = None,
              noise_scale: float = 1.0, progress: Callable[[str], None] | None = None, *, params=UNSET) -> Sweep:
    """Run every controller at every ``h`` for every noise seed (compiled, one build per controller
    and ``h``, cached on disk); the Table 2 gains unless ``gains[controller]`` is given.

    ``noise_scale`` multiplies the sensor noise (0: perfect measurements, the EKF unchanged), as in
    :func:`arvcas.sim.simulation.simulate`: it separates discretisation chattering from noise. ``system``: its
    Params (default: the default system; ``params=``: its old name).
    """
    params = renamed_system(system, params, "run_sweep")
    say = progress or (lambda _m: None)
    cfg = cfg if cfg is not None else scenario.load_scenario()
    params = params if params is not None else load_params()
    hs = tuple(float(h) for h in hs)
    if not hs:
        raise ValueError("--h: give at least one sampling period")
    if len(set(hs)) != len(hs):
        raise ValueError(f"--h: repeated sampling period in {hs}")
    cfgs = [_check_h(cfg, h) for h in hs]
    controllers = tuple(gains_mod.check_controller(c) for c in controllers)
    for c in controllers:  # the sweep measures the adaptive gain's zigzag: it needs the k1 and s signals
        have = {s.name for s in gains_mod.get(c).signals}
        if not {"k1", "s"} <= have:
            raise ValueError(f"sweep: controller '{c}' traces no adaptive gain k1 and sliding variable s "
                             f"(the sweep measures their zigzag); allowed: "
                             f"{', '.join(n for n in gains_mod.controllers() if {'k1', 's'} <= {x.name for x in gains_mod.get(n).signals})}")
    if not controllers:
        raise ValueError("--controllers: give at least one controller")
    seeds = tuple(int(s) for s in seeds)
    if not seeds or any(s < 0 for s in seeds):
        raise ValueError(f"--seeds: give non-negative integers, got {seeds}")
    if not (isinstance(noise_scale, (int, float)) and math.isfinite(noise_scale) and noise_scale >= 0):
        raise ValueError(f"--noise-scale: must be a finite number >= 0, got {noise_scale!r}")
    G = {c: np.asarray((gains or {}).get(c, gains_mod.default_gains(c, params)), dtype=float) for c in controllers}
    for c in controllers:  # RESO stability at every h before anything runs
        for cf in cfgs:
            gains_mod.check_gains(c, G[c], h=cf.time_h, where=f"gains of {c} at h = {cf.time_h:g}")
    nc, nh, ns = len(controllers), len(hs), len(seeds)
    chat = np.full((nc, nh, ns, 6), np.nan)
    rmse = np.full((nc, nh, ns, 6), np.nan)
    ok = np.zeros((nc, nh, ns), dtype=bool)
    t_fail = np.full((nc, nh, ns), np.nan)
    zz = {k: np.full((nc, nh, ns, 6), np.nan) for k in _ZZ}
    k1_0: dict[str, list[np.ndarray]] = {c: [] for c in controllers}
    for i, c in enumerate(controllers):
        for j, cf in enumerate(cfgs):
            say(f"{c} at h = {cf.time_h:g} s: {ns} seed(s)")
            for m, sd in enumerate(seeds):
                r = simulate(c, gains=G[c], seed=sd, system=params, cfg=cf, noise_scale=noise_scale)
                ok[i, j, m] = r.ok
                if r.ok:
                    chat[i, j, m], rmse[i, j, m] = r.chat, r.rmse
                    z = zigzag(r.k1, r.s, c, G[c], cf.time_h)
                    if z is not None:
                        for k in _ZZ:
                            zz[k][i, j, m] = z[k]
                else:
                    t_fail[i, j, m] = r.t_fail
                if m == 0:
                    k1_0[c].append(np.asarray(r.k1, dtype=float))
    meta = {}
    sysref = _io.system_ref(params)
    if sysref:  # another system: its name and its objectives' normalisation (docs/model.md §8)
        meta = {"system": sysref, "param_names": params.names(), "reference": _io.system_reference(params, cfg)}
    return Sweep(hs, controllers, seeds, G, chat, rmse, ok, t_fail, zz["reversals"], zz["rises_inside"],
                 zz["amplitude"], k1_0, cfg.to_toml(), params.vector(), float(noise_scale), meta)


# ---------------------------------------------------------------------------------------------
# file


def write_sweep(sw: Sweep, path) -> Path:
    """HDF5 (``format = "arvcas-sweep"``): arrays [controller, h, seed, dof], the first seed's k1
    series under ``k1/<controller>/<j>``, and everything needed to re-run it."""
    import h5py

    path = _io.target(path, str(path))

    def fill(tmp: Path) -> None:
        with _io.files.new_hdf5(tmp) as f:
            a = f.attrs
            a["format"], a["format_version"] = FORMAT, FORMAT_VERSION
            a["hs"] = np.array(sw.hs)
            a["controllers"] = np.array(sw.controllers, dtype=object)
            a["seeds"] = np.array(sw.seeds, dtype=np.int64)
            a["dofs"] = np.array(DOFS, dtype=object)
            a["axes"] = "controller, h, seed, dof"
            a["config"] = sw.config_text
            a["noise_scale"] = float(sw.noise_scale)
            a["h_plant"] = scenario.loads_scenario(sw.config_text).time_h_plant if sw.config_text else float("nan")
            a["params"] = np.asarray(sw.params_vector, float)
            a["param_names"] = np.array(list(sw.meta.get("param_names") or PARAM_SCHEMA), dtype=object)
            if sw.meta.get("system"):
                a["system"] = str(sw.meta["system"])
                if sw.meta.get("reference") is not None:
                    a["ref_chat"], a["ref_rmse"] = (np.asarray(x, float) for x in sw.meta["reference"])
            a["zigzag_definition"] = __doc__.split("Zigzag of k1", 1)[1].split("Totals are", 1)[0].strip()
            for k, v in _io.provenance().items():
                a[k] = v
            sources = _io.controller_sources(sw.controllers)
            if sources:  # controllers from plugins: which, and their sources' digests
                a["controller_sources"] = sources
            for c, g in sw.gains.items():
                ds = f.create_dataset(f"gains/{c}", data=g)
                ds.attrs["names"] = np.array(gains_mod.gain_names(c), dtype=object)
            for name in _ARRAYS:
                f.create_dataset(name, data=getattr(sw, name))
            f["chat"].attrs["units"] = "N, N m per controller sample (eq. 42)"
            f["rmse"].attrs["units"] = "m, rad (eq. 43)"
            f.create_dataset("chat_per_second", data=sw.chat / np.array(sw.hs)[None, :, None, None])
            for c, series in sw.k1_seed0.items():
                for j, k1 in enumerate(series):
                    ds = f.create_dataset(f"k1/{c}/{j}", data=k1, compression="gzip", shuffle=True)
                    ds.attrs["h"] = sw.hs[j]

    return _io.atomic_write(path, fill, FORMAT)


def read_sweep(path) -> Sweep:
    f = _io.open_h5(path, FORMAT, FORMAT_VERSION)
    try:
        a = f.attrs
        ctrls = tuple(_io.str_attr(x) for x in np.asarray(a["controllers"]).ravel())
        hs = tuple(float(x) for x in np.asarray(a["hs"]).ravel())
        return Sweep(
            hs=hs, controllers=ctrls, seeds=tuple(int(x) for x in np.asarray(a["seeds"]).ravel()),
            gains={c: np.array(f[f"gains/{c}"][()]) for c in ctrls},
            **{k: np.array(f[k][()]) for k in _ARRAYS},
            k1_seed0={c: [np.array(f[f"k1/{c}/{j}"][()]) for j in range(len(hs))] for c in ctrls},
            config_text=_io.str_attr(a["config"]), params_vector=np.array(a["params"], float),
            noise_scale=float(a["noise_scale"]),
            meta={**{k: _io.str_attr(a[k]) for k in ("arvcas_version", "casadi_version", "created", "system",
                                                     "controller_sources") if k in a},
                  **({"param_names": [_io.str_attr(x) for x in a["param_names"]],
                      "reference": (tuple(np.array(a["ref_chat"], float)), tuple(np.array(a["ref_rmse"], float)))
                      if "ref_chat" in a else None} if "system" in a else {})},
        )
    finally:
        f.close()


def reproduce_sweep(path) -> tuple[Sweep, list[str]]:
    """Re-run the sweep stored in ``path`` from its stored configuration (scenario, parameters, gains,
    periods, seeds, noise scale); returns the new sweep and the fields that differ (empty: bit for bit)."""
    old = read_sweep(path)
    _io.require_controllers(path, old.controllers, old.meta.get("controller_sources", ""))
    cfg, params = _io.stored_inputs(path, old.config_text, old.params_vector, ValueError, old.meta.get("system", ""))
    new = run_sweep(old.hs, old.controllers, old.seeds, cfg=cfg, system=params, gains=old.gains,
                    noise_scale=old.noise_scale)
    diff = [k for k in _ARRAYS if not np.array_equal(getattr(new, k), getattr(old, k), equal_nan=k != "ok")]
    diff += [f"k1/{c}" for c in old.controllers
             if not all(np.array_equal(a, b) for a, b in zip(new.k1_seed0[c], old.k1_seed0[c]))]
    return new, diff


# ---------------------------------------------------------------------------------------------
# report


def _nanmean(x, axis):
    x = np.asarray(x, dtype=float)
    cnt = np.isfinite(x).sum(axis=axis)
    s = np.nansum(x, axis=axis)
    return np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)


def _plant_steps(cfg: ScenarioConfig | None, hs) -> str:
    """The plant's RK4 step of the sweep's runs, in words."""
    if cfg is None:
        return "stays the scenario's"
    steps = {h: cfg.with_h(h).time_h_plant for h in hs}
    if len(set(steps.values())) == 1:
        return f"stays {cfg.time_h_plant:g} s"
    return "is " + ", ".join(f"{hp:g} s at h = {h:g}" for h, hp in steps.items()) + \
        f" (the scenario's {cfg.time_h_plant:g} s where it divides h)"


def sweep_markdown(sw: Sweep) -> str:
    cfg = scenario.loads_scenario(sw.config_text) if sw.config_text else None
    obj = sw.objectives()
    frac = zigzag_time_fraction(sw)
    ns = len(sw.seeds)
    noise = ("sensor noise as in the scenario" if sw.noise_scale == 1.0 else
             "no sensor noise (noise scale 0; the EKF keeps its nominal covariance)" if sw.noise_scale == 0 else
             f"sensor noise scaled by {sw.noise_scale:g}")
    system = sw.meta.get("system", "")
    L = ["# Sampling-period sweep", "",
         f"Controllers {', '.join(sw.controllers)} with their {metrics.defaults_name(system)} at h = "
         f"{', '.join(f'{h:g}' for h in sw.hs)} s (controller, sensors, EKF, ATD, RESO, GSTA; the plant's RK4 step "
         f"{_plant_steps(cfg, sw.hs)}), {noise}, noise seeds {', '.join(map(str, sw.seeds))}; "
         "the scenario's disturbance phases and nominal-model factors. Values are means over the seeds "
         f"({ns} run(s) per cell) of the completed runs. f_chat, f_rmse: docs/model.md §7 objectives (per-DOF value / "
         f"{metrics.norm_name(system)}, averaged over the 6 DOF); CHAT is per controller sample, CHAT/h per second.", "",
         "Zigzag of k1 (arvcas/beyond/sweep.py): *reversals* = samples where k1 changes direction within one "
         "adaptation step l h of k1min, summed over the 6 DOF; *time* = reversals x h / run length, mean over "
         "DOF (the fraction of the run k1 spends zigzagging); *rises inside* = samples where k1 rises although "
         "|s| <= sigma, summed over DOF; *step / k1min* = mean |Δk1| at a reversal relative to k1min (mean over "
         "the DOF with reversals). AGSTA has no k1min: n/a.", "",
         "| controller | h (s) | runs ok | f_chat | f_rmse | mean CHAT/h | reversals | time | rises inside "
         "| step / k1min |",
         "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for i, c in enumerate(sw.controllers):
        kmin = gains_mod.unpack(c, sw.gains[c]).get("k1min")
        for j, h in enumerate(sw.hs):
            nok = int(sw.ok[i, j].sum())
            fc = _nanmean(obj[i, j, :, 0], 0)
            fr = _nanmean(obj[i, j, :, 1], 0)
            cps = _nanmean(np.mean(sw.chat[i, j], axis=1) / h, 0)
            rev = sw.reversals[i, j]
            if kmin is None or np.isnan(rev).all():
                zz = "n/a | n/a | n/a | n/a"
            else:
                tot_rev = _nanmean(rev.sum(axis=1), 0)
                tot_ris = _nanmean(sw.rises_inside[i, j].sum(axis=1), 0)
                rel = np.where(rev > 0, sw.amplitude[i, j] / np.asarray(kmin, dtype=float), np.nan)
                amp_m = _nanmean(rel.ravel(), 0)
                zz = (f"{tot_rev:.1f} | {_nanmean(frac[i, j], 0):.3f} | {tot_ris:.1f} | "
                      + (f"{amp_m:.3g}" if np.isfinite(amp_m) else "-"))
            L.append(f"| {c} | {h:g} | {nok}/{ns} | {fc:.4g} | {fr:.4g} | {cps:.4g} | {zz} |")
    for key, unit in (("chat", "N, N m per sample"), ("rmse", "m, rad"), ("reversals", "count")):
        L += ["", f"## {key} per DOF ({unit}), mean over seeds", "",
              "| controller | h (s) | " + " | ".join(_DOF_MD) + " |", "|---|---:|" + "---:|" * 6]
        arr = getattr(sw, key)
        for i, c in enumerate(sw.controllers):
            for j, h in enumerate(sw.hs):
                v = _nanmean(arr[i, j], 0)
                fmt = ".1f" if key == "reversals" else ".4g"
                L.append(f"| {c} | {h:g} | " + " | ".join("n/a" if np.isnan(x) else f"{x:{fmt}}" for x in v) + " |")
    bad = [(sw.controllers[i], sw.hs[j], sw.seeds[m], sw.t_fail[i, j, m]) for i, j, m in zip(*np.nonzero(~sw.ok))]
    if bad:
        L += ["", "## Diverged runs", ""]
        L += [f"- {c} at h = {h:g} s, seed {s}: diverged at t = {t:g} s" for c, h, s, t in bad]
    L.append("")
    return "\n".join(L)




def zigzag_time_fraction(sw: Sweep) -> np.ndarray:
    """Fraction of the run spent reversing near k1min, reversals h / duration, mean over the 6 DOF:
    [controller, h, seed] (NaN for agsta)."""
    T = scenario.loads_scenario(sw.config_text).time_duration if sw.config_text else 100.0
    return np.mean(sw.reversals, axis=3) * np.array(sw.hs)[None, :, None] / T


def plot_sweep(sw: Sweep, fig: Figure | None = None, dof: int = 0,
               window: tuple[float, float] = (70.0, 73.0)) -> Figure:
    """Six panels against h: f_chat per unit time (scaled to h = 0.1 s), f_rmse, the time fraction k1
    spends zigzagging, the reversal
    count, the zigzag step (mean |dk1| at reversals, relative to k1min); and k1 - k1min of DOF ``dof``
    over ``window`` (s) for the traditional law at the shortest and longest h and the proposed law
    at the longest h."""
    return _plot_sweep(sw, fig, dof, window)


@style.styled
def _plot_sweep(sw: Sweep, fig, dof: int, window: tuple[float, float]) -> Figure:
    if fig is None:
        fig = style.figure("page", 5.4)
    axs = fig.subplots(2, 3)
    obj = sw.objectives()
    hs = np.array(sw.hs)
    frac = zigzag_time_fraction(sw)
    for i, c in enumerate(sw.controllers):
        col = controller_color(c, i)
        for k, ax in enumerate((axs[0, 0], axs[0, 1])):
            # CHAT per sample grows with h for the same slew rate: scale it to the paper's h = 0.1 s
            v = obj[i, :, :, k] * (0.1 / hs[:, None] if k == 0 else 1.0)
            m = _nanmean(v, 1)
            lo, hi = np.nanmin(v, axis=1), np.nanmax(v, axis=1)
            ax.errorbar(hs, m, yerr=[m - lo, hi - m], color=col, marker="o", capsize=2, label=c)
        rev = sw.reversals[i]
        if np.isnan(rev).all():
            continue
        axs[0, 2].plot(hs, _nanmean(frac[i], 1), color=col, marker="o", label=c)
        axs[1, 0].plot(hs, _nanmean(rev.sum(axis=2), 1), color=col, marker="o", label=c)
        kmin = np.asarray(gains_mod.unpack(c, sw.gains[c])["k1min"], dtype=float)
        step = np.where(rev > 0, sw.amplitude[i] / kmin, np.nan)  # [h, seed, dof]
        axs[1, 1].plot(hs, _nanmean(step.reshape(len(hs), -1), 1), color=col, marker="o", label=c)
    ylabels = {
        (0, 0): "f_chat x (0.1 s / h)", (0, 1): "f_rmse",
        (0, 2): "fraction of the run (mean over DOF)", (1, 0): "reversals near k1min (sum over 6 DOF)",
        (1, 1): "mean |Δk1| at a reversal / k1min",
    }
    titles = {(0, 0): "CHAT per unit time (eq. 42 / h, scaled to h = 0.1 s)", (0, 1): "RMSE (eq. 43)",
              (0, 2): "time k1 spends zigzagging near k1min", (1, 0): "k1 reversals near k1min",
              (1, 1): "size of one zigzag step"}
    for (r, c), lab in ylabels.items():
        ax = axs[r, c]
        ax.set_ylabel(lab)
        ax.set_title(titles[(r, c)])
        ax.set_xscale("log")
        ax.set_xticks(hs, [f"{h:g}" for h in hs])
        ax.minorticks_off()
        ax.set_xlabel("controller sampling period h (s)")
        ax.grid(True, alpha=0.5)
        ax.legend()
    axs[1, 0].set_yscale("symlog", linthresh=10.0)
    axs[1, 0].set_ylim(bottom=0.0)
    ax = axs[1, 2]
    jmin, jmax = int(np.argmin(hs)), int(np.argmax(hs))
    for c, j, col, ls in (("traditional", jmin, style.color("orange"), "-"),
                          ("traditional", jmax, style.color("vermillion"), "-"),
                          ("proposed", jmax, style.color("tab:blue"), "--")):
        if c not in sw.controllers:
            continue
        kmin = gains_mod.unpack(c, sw.gains[c])["k1min"][dof]
        k1 = sw.k1_seed0[c][j][:, dof]
        t = sw.hs[j] * np.arange(k1.size)
        sel = (t >= window[0]) & (t <= window[1])
        ax.step(t[sel], k1[sel] - kmin, where="post", color=col, ls=ls, label=f"{c}, h = {sw.hs[j]:g} s")
    ax.axhline(0.0, color="0.3", ls=":", lw=0.8)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"k1 - k1min, DOF {DOFS[dof]}")
    ax.set_title(f"k1 near k1min (DOF {DOFS[dof]}, seed {sw.seeds[0]})")
    ax.grid(True, alpha=0.5)
    ax.legend(loc="upper right")
    ns = sw.noise_scale
    cfg = scenario.loads_scenario(sw.config_text) if sw.config_text else None
    system = sw.meta.get("system", "")
    fig.suptitle(f"Sampling-period sweep: {metrics.defaults_name(system)}, plant RK4 step {_plant_steps(cfg, sw.hs)};"
                 f" f = mean over DOF of value / {metrics.norm_name(system)}"
                 + ("" if ns == 1.0 else f", sensor noise x {ns:g}")
                 + f"; mean over {len(sw.seeds)} seed(s), bars min..max")
    return fig


def write_sweep_dir(sw: Sweep, out_dir, fmt: str = "png") -> dict[str, Path]:
    """``out_dir/sweep.h5``, ``sweep.md`` and ``sweep.png`` (or ``.pdf``, ``.svg``; each written atomically)."""
    return _io.write_result_dir(out_dir, "sweep", sw, write_sweep, sweep_markdown, plot_sweep, fmt)
