"""Figures of runs (the paper's Figures 5-11 and the same for any system) from
:class:`arvcas.sim.simulation.Result` objects.

Every function takes results, an optional ``fig`` (an empty :class:`matplotlib.figure.Figure`
to draw into) and ``title``, and returns the Figure; nothing here calls ``pyplot`` (no global figure
registry, no ``show``): write it with :func:`arvcas.io.style.write_figure` (PNG, PDF or SVG). Figures
are drawn in the house style (:mod:`arvcas.io.style`: page width, journal font sizes, the
colour-blind-safe palette; dense noisy series as min-max bands). Titles name no paper figure; `arvcas
paper` passes its own ("(Fig. 5)"). Figures with one panel per DOF have six axes in 3 rows x 2 columns:
x, y, z down the left column, phi, theta, psi down the right one; ``fig.axes[i]`` is DOF ``i``. The
thrust figure has one panel per thruster of the run's system (its names), down the left column first.

==========  =======================  ==========================================================
paper       function                 content
==========  =======================  ==========================================================
Figure 5    :func:`plot_states`      eta of each run (solid) and the ATD reference y1 (dashed)
Figure 6    :func:`plot_errors`      e = eta - eta_ref of each run
Figure 7    :func:`plot_thrusts`     the thrusts after saturation (limits drawn when reached)
Figure 8    :func:`plot_sliding`     s of each run with its +-sigma band (Table 2)
Figure 9    :func:`plot_gains`       k1 of each run (k1min dotted where the law has one)
Figure 10   :func:`plot_zigzag`      k1, traditional vs proposed law, inset magnified near k1min
Figure 11   :func:`plot_disturbance` RESO estimate f_hat vs true total disturbance f_true
==========  =======================  ==========================================================

A diverged run (``ok = False``) is drawn up to ``t_fail`` only (later samples repeat the frozen
state) and its legend entry says where it diverged.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from matplotlib.figure import Figure

from arvcas.controllers import gains as gains_mod
from arvcas.io import style
from arvcas.system.params import SCHEMA as PARAM_SCHEMA
from arvcas.system.params import load as load_params

__all__ = [
    "plot_states", "plot_errors", "plot_thrusts", "plot_sliding", "plot_gains", "plot_zigzag",
    "plot_disturbance", "FIGURES", "DOF_LABELS", "thruster_names", "controller_label", "controller_color",
]

DOF_LABELS = (r"$x$", r"$y$", r"$z$", r"$\phi$", r"$\theta$", r"$\psi$")
_LIN = ("m", "m", "m", "rad", "rad", "rad")
_RATE = ("m/s", "m/s", "m/s", "rad/s", "rad/s", "rad/s")
_FORCE = ("N", "N", "N", "N m", "N m", "N m")


def controller_label(name: str) -> str:
    """A controller's display name (its ``label``; the name itself for one not registered here)."""
    try:
        return gains_mod.get(name).label or name
    except ValueError:
        return name


def controller_color(name: str, i: int = 0) -> str:
    """A controller's colour in the house palette (its ``color`` through :func:`arvcas.io.style.color`,
    else the palette's colour ``i``)."""
    try:
        c = gains_mod.get(name).color
    except ValueError:
        c = ""
    return style.color(c, i)


_HEIGHT = 6.0  # in, six-panel figures at page width


def thruster_names(r) -> tuple[str, ...]:
    """The names of the run's thrusters in allocation order: from its system's parameters
    (``thrusters.<name>.u_min``); a run that records no system is of the default system
    (:data:`arvcas.system.DEFAULT`), whose names it takes; ``T1 .. Tn`` if the count differs."""
    from arvcas.system import DEFAULT, load_system

    n = np.asarray(r.thrust).shape[1]
    names = [k.split(".")[1] for k in (r.meta.get("param_names") or ()) if k.startswith("thrusters.")
             and k.endswith(".u_min") and k.count(".") == 2]
    if len(names) == n:
        return tuple(names)
    if not r.meta.get("system"):
        names = list(load_system(DEFAULT).structure.thruster_names())
        if len(names) == n:
            return tuple(names)
    return tuple(f"T{j + 1}" for j in range(n))


# ---------------------------------------------------------------------------------------------
# helpers


def _as_list(results) -> list:
    if hasattr(results, "controller") and hasattr(results, "t"):
        return [results]
    if not isinstance(results, Iterable):
        raise TypeError(f"expected a Result or a sequence of Results, got {type(results).__name__}")
    out = list(results)
    if not out:
        raise ValueError("no results to plot")
    for r in out:
        if not (hasattr(r, "controller") and hasattr(r, "t")):
            raise TypeError(f"expected Result objects, got {type(r).__name__}")
    return out


def _label(r) -> str:
    name = controller_label(r.controller)
    return name if r.ok else f"{name} (diverged at {r.t_fail:g} s)"


def _color(r, i: int) -> str:
    return controller_color(r.controller, i)


def _z(j: int) -> float:
    """z-order of the j-th run: the first run (e.g. the proposed controller) is drawn on top."""
    return 2.5 - 0.1 * j


def _valid(r) -> np.ndarray:
    """Sample indices to draw: all, or up to t_fail for a diverged run."""
    t = np.asarray(r.t)
    if r.ok or r.t_fail is None:
        return np.arange(t.size)
    return np.flatnonzero(t <= r.t_fail + 1e-9)


def _six(fig: Figure | None, title: str, n: int = 6) -> tuple[Figure, list]:
    """``n`` panels in two columns (left column first: x, y, z then phi, theta, psi for six), shared time axis."""
    rows = (n + 1) // 2
    if fig is None:
        fig = style.figure("page", _HEIGHT * max(rows, 3) / 3)
    elif fig.axes:
        raise ValueError(f"fig must be empty (the function adds its own {rows} x 2 axes)")
    # created in panel order (so fig.axes[i] is DOF or thruster i): down the left column, then the right one
    axes: list = []
    for i in range(n):
        col, row = divmod(i, rows)
        ax = fig.add_subplot(rows, 2, 2 * row + col + 1, sharex=axes[0] if axes else None)
        if row == rows - 1 or i == n - 1:  # the last panel of its column
            ax.set_xlabel("time (s)")
        else:
            ax.tick_params(labelbottom=False)
        ax.grid(True, alpha=0.5)
        ax.margins(x=0)
        axes.append(ax)
    fig.suptitle(title)
    return fig, axes


def _legend(fig: Figure, axes) -> None:
    """One legend for the figure, below the axes, from the labelled artists of all axes (first wins)."""
    seen: dict[str, object] = {}
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lab, h)
    handles, labels = list(seen.values()), list(seen)
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncols=min(len(labels), 3), frameon=False)


def _sub(i: int) -> str:
    """TeX of DOF i without dollars, for subscripts: x, y, z, \\phi, \\theta, \\psi."""
    return DOF_LABELS[i].strip("$")


def _gain(r, name: str) -> np.ndarray | None:
    """Per-DOF Table 2 column ``name`` of the run's own gains, or None if its controller has none."""
    cols = gains_mod.columns(r.controller)
    if name not in cols:
        return None
    return np.asarray(gains_mod.unpack(r.controller, np.asarray(r.gains, dtype=float))[name], dtype=float)


def _thrust_limits(r, j: int) -> tuple[float, float]:
    """[u_min, u_max] of thruster ``j`` from the run's parameters (a shared pair for Haidou-1)."""
    pv = r.params_vector
    if pv is None:
        pv = load_params().vector()
    names = list(r.meta.get("param_names") or PARAM_SCHEMA)
    idx = {n: i for i, n in enumerate(names)}
    own = thruster_names(r)[j]
    lo = idx.get(f"thrusters.{own}.u_min", idx.get("thrusters.u_min"))
    hi = idx.get(f"thrusters.{own}.u_max", idx.get("thrusters.u_max"))
    if lo is None or hi is None:  # pragma: no cover - every system has limits
        return -np.inf, np.inf
    return float(pv[lo]), float(pv[hi])


def _same_refs(rs) -> bool:
    ref0 = np.asarray(rs[0].eta_ref)
    return all(np.asarray(r.eta_ref).shape == ref0.shape and np.allclose(r.eta_ref, ref0, rtol=0, atol=1e-12)
               for r in rs[1:])


# ---------------------------------------------------------------------------------------------
# Figures 5-11


@style.styled
def plot_states(results, fig: Figure | None = None, title: str = "Vehicle states during station keeping") -> Figure:
    """Figure 5: eta (solid, one line per run) and the ATD reference y1 (dashed) per DOF.

    Runs sharing one seed have the same reference (y1 starts at the EKF's first estimate); it is then
    drawn once, in black, else once per run in the run's colour. Units m and rad, frame {n}.
    """
    rs = _as_list(results)
    fig, axes = _six(fig, title)
    shared = _same_refs(rs)
    for i, ax in enumerate(axes):
        for j, r in enumerate(rs):
            k = _valid(r)
            style.trace(ax, r.t[k], r.eta[k, i], color=_color(r, j), label=_label(r), zorder=_z(j))
        for j, r in enumerate(rs[:1] if shared else rs):
            k = _valid(r)
            lab = "ATD reference $y_1$" if shared else f"reference $y_1$ ({controller_label(r.controller)})"
            ax.plot(r.t[k], r.eta_ref[k, i], ls="--", color="k" if shared else _color(r, j), label=lab)
        ax.set_ylabel(f"{DOF_LABELS[i]} ({_LIN[i]})")
    _legend(fig, axes)
    return fig


@style.styled
def plot_errors(results, fig: Figure | None = None, title: str = r"State errors $e = \eta - y_1$") -> Figure:
    """Figure 6: tracking error e = eta - eta_ref per DOF (m, rad; {n}), one line per run."""
    rs = _as_list(results)
    fig, axes = _six(fig, title)
    for i, ax in enumerate(axes):
        for j, r in enumerate(rs):
            k = _valid(r)
            style.trace(ax, r.t[k], (r.eta - r.eta_ref)[k, i], color=_color(r, j), label=_label(r), zorder=_z(j))
        ax.axhline(0.0, color="0.3", lw=0.5)
        ax.set_ylabel(f"$e_{{{_sub(i)}}}$ ({_LIN[i]})")
    _legend(fig, axes)
    return fig


@style.styled
def plot_thrusts(results, fig: Figure | None = None, title: str = "Thrust per thruster") -> Figure:
    """Figure 7: thrust per thruster after saturation (N), one panel per thruster of the runs' system
    (its names, :func:`thruster_names`), one line per run.

    The saturation limits [u_min, u_max] (from each run's parameters) are drawn as dotted grey lines
    on the panels where some run reaches them.
    """
    rs = _as_list(results)
    names = thruster_names(rs[0])
    if any(thruster_names(r) != names for r in rs[1:]):
        raise ValueError("plot_thrusts: the runs have different thrusters (runs of one system only)")
    fig, axes = _six(fig, title, len(names))
    for i, ax in enumerate(axes):
        hit = set()
        for j, r in enumerate(rs):
            k = _valid(r)
            u = np.asarray(r.thrust)[k, i]
            style.trace(ax, r.t[k], u, color=_color(r, j), label=_label(r), zorder=_z(j))
            lo, hi = _thrust_limits(r, i)
            if u.size and u.min() <= lo + 1e-6:
                hit.add(lo)
            if u.size and u.max() >= hi - 1e-6:
                hit.add(hi)
        for lim in sorted(hit):
            ax.axhline(lim, color="0.2", ls=":", lw=1.0, label="saturation limit")
        ax.set_ylabel("thrust (N)")
        ax.set_title(names[i])
    _legend(fig, axes)
    return fig


@style.styled
def plot_sliding(results, fig: Figure | None = None,
                 title: str = r"Sliding variables $s$ and $\pm\sigma$ bands") -> Figure:
    """Figure 8: sliding variable s per DOF (m/s, rad/s; {n}), with each run's band |s| <= sigma.

    sigma comes from the run's own gains (its ``sigma`` column) and is drawn as a shaded band in
    the run's colour; the y-range is symmetric and holds the whole series and every band.
    """
    rs = _as_list(results)
    fig, axes = _six(fig, title)
    for i, ax in enumerate(axes):
        ymax = 0.0
        for j, r in enumerate(rs):
            k = _valid(r)
            c = _color(r, j)
            s = np.asarray(r.s)[k, i]
            style.trace(ax, r.t[k], s, color=c, label=_label(r), zorder=_z(j))
            sig = _gain(r, "sigma")
            if sig is not None:
                name = controller_label(r.controller)
                ax.axhspan(-sig[i], sig[i], facecolor=(c, 0.13), edgecolor=c, ls="--", lw=0.6, zorder=1,
                           label=rf"$\pm\sigma$ ({name})")
                ymax = max(ymax, 1.5 * sig[i])
            finite = s[np.isfinite(s)]
            if finite.size:
                ymax = max(ymax, 1.05 * float(np.max(np.abs(finite))))
        if ymax > 0:
            ax.set_ylim(-ymax, ymax)
        ax.set_ylabel(f"$s_{{{_sub(i)}}}$ ({_RATE[i]})")
    _legend(fig, axes)
    return fig


@style.styled
def plot_gains(results, fig: Figure | None = None, title: str = r"Adaptive gains $k_1$") -> Figure:
    """Figure 9: adaptive gain k1 per DOF (the gain's units), one line per run.

    For laws with a floor (proposed, traditional, implicit) the run's k1min is a dotted line.
    """
    rs = _as_list(results)
    fig, axes = _six(fig, title)
    for i, ax in enumerate(axes):
        for j, r in enumerate(rs):
            k = _valid(r)
            c = _color(r, j)
            style.trace(ax, r.t[k], np.asarray(r.k1)[k, i], color=c, label=_label(r), zorder=_z(j))
            kmin = _gain(r, "k1min")
            if kmin is not None:
                name = controller_label(r.controller)
                ax.axhline(kmin[i], color=c, ls=":", lw=0.8, label=f"$k_{{1\\min}}$ ({name})")
        ax.set_ylabel(f"$k_{{1,{_sub(i)}}}$")
    _legend(fig, axes)
    return fig


def _zoom_window(t: np.ndarray, k1_trad: np.ndarray, kmin: float, step: float, span: float, run: int = 10):
    """Time window (t0, t1) and k1 range (lo, hi) for the magnified view.

    Centred on where the traditional law's k1 settles into its zigzag: the first stretch of ``run``
    samples within one step ``l h`` of k1min (preferably entered from above); else the closest
    approach of k1 to k1min. ``span`` is at most a quarter of the run.
    """
    span = min(span, 0.25 * float(t[-1] - t[0])) if t.size > 1 else span
    inband = np.abs(k1_trad - kmin) <= step * (1 + 1e-9)
    starts = []
    count = 0
    for idx, b in enumerate(inband):
        count = count + 1 if b else 0
        if count == run:
            starts.append(idx - run + 1)
    from_above = [i for i in starts if i > 0 and k1_trad[i - 1] > kmin + step]
    if from_above or starts:
        t0 = max(float(t[0]), float(t[(from_above or starts)[0]]) - 0.25 * span)
    else:  # never settles: centre on the closest approach to k1min
        t0 = max(float(t[0]), float(t[int(np.argmin(np.abs(k1_trad - kmin)))]) - 0.5 * span)
    t1 = min(float(t[-1]), t0 + span)
    t0 = max(float(t[0]), min(t0, t1 - span))
    m = (t >= t0) & (t <= t1)
    lo = min(kmin - 1.5 * step, float(np.min(k1_trad[m])) if m.any() else kmin)
    hi = kmin + 3.0 * step
    return t0, t1, lo, hi


@style.styled
def plot_zigzag(traditional, proposed, fig: Figure | None = None, span: float = 5.0,
                title: str = r"$k_1$: traditional vs proposed adaptive law") -> Figure:
    """Figure 10: k1 of the traditional decreasing law vs the proposed law (eq. 19), per DOF.

    Each panel has an inset magnifying ``span`` seconds where the traditional gain reaches k1min
    (k1min - 1.5 l h .. k1min + 3 l h vertically, l h being one step of the traditional law): the
    discretised traditional law zigzags there by +-l h per sample, the proposed one stops at k1min.
    The inset draws every sample; the main panel draws a zigzag too dense for its width as a band.
    """
    tr, pr = _as_list(traditional)[0], _as_list(proposed)[0]
    fig, axes = _six(fig, title)
    kmin = _gain(tr, "k1min")
    kmin_p = _gain(pr, "k1min")
    ell = _gain(tr, "l")
    if kmin is None or ell is None:
        raise ValueError(f"plot_zigzag: the traditional run's controller '{tr.controller}' has no k1min/l gains")
    for i, ax in enumerate(axes):
        ktr, kpr = _valid(tr), _valid(pr)
        lines = [
            (tr.t[ktr], np.asarray(tr.k1)[ktr, i], _color(tr, 0), _label(tr)),
            (pr.t[kpr], np.asarray(pr.k1)[kpr, i], _color(pr, 1), _label(pr)),
        ]
        for t, k1, c, lab in lines:
            style.trace(ax, t, k1, color=c, label=lab)
        ax.axhline(kmin[i], color="0.3", ls=":", lw=0.8, label=r"$k_{1\min}$")
        ax.set_ylabel(f"$k_{{1,{_sub(i)}}}$")
        step = float(ell[i]) * float(tr.h)
        t0, t1, lo, hi = _zoom_window(np.asarray(tr.t)[ktr], lines[0][1], float(kmin[i]), step, span)
        if kmin_p is not None:
            lo = min(lo, float(kmin_p[i]) - 1.5 * step)
        ins = ax.inset_axes([0.52, 0.42, 0.45, 0.52])
        for t, k1, c, _lab in lines:
            ins.plot(t, k1, color=c, lw=0.7, marker=".", ms=2.0)
        ins.axhline(kmin[i], color="0.3", ls=":", lw=0.8)
        ins.set_xlim(t0, t1)
        ins.set_ylim(lo, hi)
        ins.tick_params(labelsize=6)
        ins.set_title("magnified", fontsize=6, pad=2)
        ax.indicate_inset_zoom(ins, edgecolor="0.4")
    _legend(fig, axes)
    return fig


@style.styled
def plot_disturbance(result, fig: Figure | None = None, title: str | None = None) -> Figure:
    """Figure 11: the controller's total-disturbance estimate f_hat (RESO: Mhat z2) against the true
    total disturbance f_true of eq. 6, per DOF (N, N m; {n}), for one run (the proposed controller).
    ``title``: default "Total disturbance: <estimate> vs simulated (<controller>)"."""
    r = _as_list(result)[0]
    est = "RESO estimate" if r.controller != "agsta" else "nominal-model estimate"
    fig, axes = _six(fig, title or f"Total disturbance: {est} vs simulated ({controller_label(r.controller)})")
    k = _valid(r)
    for i, ax in enumerate(axes):
        style.trace(ax, r.t[k], np.asarray(r.f_true)[k, i], color="k", label="simulated $f$ (eq. 6)")
        style.trace(ax, r.t[k], np.asarray(r.f_hat)[k, i], color=_color(r, 0), ls="--", label=rf"{est} $\hat f$")
        ax.set_ylabel(f"$f_{{{_sub(i)}}}$ ({_FORCE[i]})")
    _legend(fig, axes)
    return fig


# paper figure number -> (function, which runs it takes)
FIGURES = {
    "fig05": plot_states,
    "fig06": plot_errors,
    "fig07": plot_thrusts,
    "fig08": plot_sliding,
    "fig09": plot_gains,
    "fig10": plot_zigzag,
    "fig11": plot_disturbance,
}
