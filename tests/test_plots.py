"""Figures 5-11 (arvcas.io.plots) on short synthetic Results: axes, lines, labels, legends; no simulation."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from arvcas.controllers import gains as gains_mod  # noqa: E402
from arvcas.io import plots  # noqa: E402
from arvcas.system.params import load as load_params  # noqa: E402
from arvcas.sim.simulation import Result  # noqa: E402

pytestmark = pytest.mark.floor  # the figures at matplotlib's floor (CI's floor job, docs/testing.md)

N = 51  # 5 s at h = 0.1 s
H = 0.1


def synthetic(controller: str, seed: int = 0, ok: bool = True, t_fail=None, shift_ref: float = 0.0) -> Result:
    rng = np.random.default_rng(seed)
    t = np.arange(N) * H
    g = gains_mod.default_gains(controller)
    G = {k: np.array(v) for k, v in gains_mod.unpack(controller, g).items()}
    decay = np.repeat(np.exp(-t)[:, None], 6, axis=1)
    eta = 0.02 * decay + 1e-4 * rng.normal(size=(N, 6))
    eta_ref = 0.02 * decay + shift_ref
    if controller == "traditional":  # zigzag around k1min after 1 s
        k1 = np.where(t[:, None] < 1.0, G["k1min"] + 1.0 - t[:, None],
                      G["k1min"] + G["l"] * H * (np.arange(N)[:, None] % 2))
    elif "k1min" in G:
        k1 = np.maximum(G["k1min"] + 1.0 - t[:, None], G["k1min"])
    else:
        k1 = G["k1_0"] + 0.1 * t[:, None]
    thrust = 20 * rng.normal(size=(N, 6))  # far from the limits [-146.9, 231.6] N
    thrust[3, 0] = load_params()["thrusters.u_max"]  # thruster 1 saturates once
    return Result(
        controller=controller, gains=g, seed=seed, t=t, eta=eta, nu=rng.normal(size=(N, 6)) * 1e-3,
        eta_hat=eta + 1e-4, eta_ref=eta_ref, tau_cmd=rng.normal(size=(N, 6)), thrust=thrust,
        s=1e-3 * rng.normal(size=(N, 6)), k1=k1, k2=2 * k1, f_hat=rng.normal(size=(N, 6)),
        f_true=rng.normal(size=(N, 6)), q=np.zeros((N, 6)), payload=np.zeros(N),
        chat=np.ones(6), rmse=np.ones(6) * 1e-3, ok=ok, t_fail=t_fail, h=H,
    )


@pytest.fixture(scope="module")
def runs():
    return {c: synthetic(c, seed=i) for i, c in enumerate(("proposed", "agsta", "traditional"))}


def n_lines(ax) -> int:
    return len(ax.get_lines())


def check_common(fig, n_axes=6):
    assert isinstance(fig, Figure)
    assert len(fig.axes) == n_axes
    assert len(fig.legends) == 1 and fig.legends[0].get_texts()
    main = fig.axes[:6]
    for ax in main:
        assert ax.get_ylabel(), "every panel has a y label"
    assert sum(ax.get_xlabel() == "time (s)" for ax in main) == 2  # bottom row
    fig.savefig(io.BytesIO(), format="png", dpi=40)  # renders (mathtext labels included)


def test_fig05_states_shared_reference(runs):
    fig = plots.plot_states([runs["proposed"], runs["agsta"]])
    check_common(fig)
    for ax in fig.axes:
        assert n_lines(ax) == 3  # proposed, AGSTA, one shared ATD reference
    assert fig.axes[0].get_ylabel() == "$x$ (m)" and fig.axes[3].get_ylabel() == r"$\phi$ (rad)"
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == ["Proposed", "AGSTA", "ATD reference $y_1$"]


def test_fig05_states_distinct_references():
    fig = plots.plot_states([synthetic("proposed"), synthetic("agsta", shift_ref=1e-3)])
    check_common(fig)
    assert all(n_lines(ax) == 4 for ax in fig.axes)


def test_fig06_errors(runs):
    fig = plots.plot_errors([runs["proposed"], runs["agsta"]])
    check_common(fig)
    assert all(n_lines(ax) == 3 for ax in fig.axes)  # two runs + zero line
    y = fig.axes[0].get_lines()[0].get_ydata()
    np.testing.assert_allclose(y, runs["proposed"].eta[:, 0] - runs["proposed"].eta_ref[:, 0])
    assert fig.axes[2].get_ylabel() == "$e_{z}$ (m)"


def test_fig07_thrusts(runs):
    fig = plots.plot_thrusts([runs["proposed"], runs["agsta"]])
    check_common(fig)
    assert n_lines(fig.axes[0]) == 3  # two runs + the u_max line reached by thruster 1
    assert all(n_lines(ax) == 2 for ax in fig.axes[1:])
    assert all(ax.get_ylabel() == "thrust (N)" for ax in fig.axes)
    assert "saturation limit" in [t.get_text() for t in fig.legends[0].get_texts()]


def test_fig08_sliding_bands_from_gains(runs):
    p, a = runs["proposed"], runs["agsta"]
    fig = plots.plot_sliding([p, a])
    check_common(fig)
    sig_p = gains_mod.unpack("proposed", p.gains)["sigma"]
    sig_a = gains_mod.unpack("agsta", a.gains)["sigma"]
    for i, ax in enumerate(fig.axes):
        assert n_lines(ax) == 2
        bands = ax.patches
        assert len(bands) == 2
        # axhspan gives a Rectangle (matplotlib >= 3.9) or a Polygon; its data y-extent is [-sigma, sigma]
        ys = [np.asarray(b.get_patch_transform().transform(b.get_path().vertices))[:, 1] for b in bands]
        np.testing.assert_allclose(sorted(y.max() for y in ys), sorted([sig_p[i], sig_a[i]]))
        np.testing.assert_allclose(sorted(-y.min() for y in ys), sorted([sig_p[i], sig_a[i]]))
        lo, hi = ax.get_ylim()
        assert hi >= max(sig_p[i], sig_a[i]) and lo == -hi
    assert fig.axes[3].get_ylabel() == r"$s_{\phi}$ (rad/s)"


def test_fig09_gains(runs):
    fig = plots.plot_gains([runs["proposed"], runs["agsta"]])
    check_common(fig)
    kmin = gains_mod.unpack("proposed", runs["proposed"].gains)["k1min"]
    for i, ax in enumerate(fig.axes):
        lines = ax.get_lines()
        assert len(lines) == 3  # proposed k1, its k1min, AGSTA k1
        assert lines[1].get_ydata()[0] == pytest.approx(kmin[i])


def test_fig10_zigzag_inset(runs):
    fig = plots.plot_zigzag(runs["traditional"], runs["proposed"])
    check_common(fig)  # six panels; each has its inset as a child axes
    kmin = gains_mod.unpack("traditional", runs["traditional"].gains)["k1min"]
    for i, ax in enumerate(fig.axes[:6]):
        assert n_lines(ax) == 3  # traditional, proposed, k1min
        insets = [c for c in ax.child_axes]
        assert len(insets) == 1
        ins = insets[0]
        assert n_lines(ins) == 3
        lo, hi = ins.get_ylim()
        assert lo < kmin[i] < hi and hi - lo < 1.0  # magnified near k1min
        t0, t1 = ins.get_xlim()
        assert 0.0 <= t0 < t1 <= 5.0 + 1e-9


def test_fig11_disturbance(runs):
    fig = plots.plot_disturbance(runs["proposed"])
    check_common(fig)
    assert all(n_lines(ax) == 2 for ax in fig.axes)
    assert fig.axes[0].get_ylabel() == "$f_{x}$ (N)" and fig.axes[5].get_ylabel() == r"$f_{\psi}$ (N m)"


def test_draws_into_given_figure(runs):
    fig = Figure()
    out = plots.plot_errors(runs["proposed"], fig=fig)
    assert out is fig and len(fig.axes) == 6
    with pytest.raises(ValueError, match="empty"):
        plots.plot_errors(runs["proposed"], fig=fig)


def test_diverged_run_drawn_to_t_fail():
    bad = synthetic("agsta", ok=False, t_fail=2.0)
    fig = plots.plot_errors([synthetic("proposed"), bad])
    line = fig.axes[0].get_lines()[1]
    assert max(line.get_xdata()) <= 2.0 + 1e-9
    assert "diverged at 2 s" in line.get_label()


def test_no_pyplot_figures(runs):
    import matplotlib.pyplot as plt

    before = plt.get_fignums()
    for name, fn in plots.FIGURES.items():
        if name == "fig10":
            fn(runs["traditional"], runs["proposed"])
        elif name == "fig11":
            fn(runs["proposed"])
        else:
            fn([runs["proposed"], runs["agsta"]])
    assert plt.get_fignums() == before


def test_rejects_non_results():
    with pytest.raises(TypeError):
        plots.plot_states([1, 2])
    with pytest.raises(ValueError):
        plots.plot_states([])


# ---- the house style (arvcas.io.style) ---------------------------------------------------------------------------


def test_titles_name_no_paper_figure(runs):
    figs = [plots.plot_states([runs["proposed"]]), plots.plot_errors([runs["proposed"]]),
            plots.plot_thrusts([runs["proposed"]]), plots.plot_sliding([runs["proposed"]]),
            plots.plot_gains([runs["proposed"]]), plots.plot_zigzag(runs["traditional"], runs["proposed"]),
            plots.plot_disturbance(runs["proposed"])]
    for fig in figs:
        assert "Fig." not in fig.get_suptitle() and fig.get_suptitle()
    assert plots.plot_states([runs["proposed"]], title="T (Fig. 5)").get_suptitle() == "T (Fig. 5)"


def test_house_style_sizes_fonts_and_palette(runs):
    from arvcas.io import style

    fig = plots.plot_errors([runs["proposed"], runs["agsta"]])
    assert fig.get_figwidth() == pytest.approx(style.PAGE_WIDTH)
    ax = fig.axes[0]
    assert ax.yaxis.label.get_fontsize() == 8 and ax.get_yticklabels()[0].get_fontsize() == 7
    colors = [ln.get_color() for ln in ax.get_lines()[:2]]
    assert colors == [style.color("tab:blue"), style.color("tab:red")] == ["#0072B2", "#D55E00"]
    assert set(style.PALETTE.values()) >= set(colors)
    import matplotlib

    assert matplotlib.rcParams["font.size"] != 8 or matplotlib.rcParams["svg.fonttype"] != "none"  # no global change


def test_dense_noisy_series_drawn_as_a_band_smooth_ones_sample_by_sample():
    from matplotlib.collections import PolyCollection

    from arvcas.io import style

    t = np.arange(3001) * 0.02
    rng = np.random.default_rng(1)
    noisy = np.sin(0.2 * t) + 0.3 * rng.normal(size=t.size)
    smooth = np.sin(0.2 * t)
    fig = style.figure("column")
    ax = fig.add_subplot()
    band_line = style.trace(ax, t, noisy, color="k")
    line = style.trace(ax, t, smooth, color="k")
    assert line.get_xdata().size == t.size  # every sample
    bins = band_line.get_xdata().size
    assert 50 <= bins < t.size / style.SAMPLES_PER_POINT
    bands = [c for c in ax.collections if isinstance(c, PolyCollection)]
    assert len(bands) == 1
    ys = bands[0].get_paths()[0].vertices[:, 1]
    assert ys.max() == pytest.approx(noisy.max()) and ys.min() == pytest.approx(noisy.min())
    np.testing.assert_allclose(band_line.get_ydata().mean(), noisy.mean(), atol=0.02)
    few = style.trace(ax, t[:200], noisy[:200])  # few samples: drawn as they are
    assert few.get_xdata().size == 200


def test_thrust_figure_takes_the_systems_thrusters():
    r = synthetic("proposed")
    names = [f"thrusters.P{j}.{k}" for j in range(1, 9) for k in ("position.x", "u_min", "u_max")]
    N = r.t.size
    r8 = Result(controller="proposed", gains=r.gains, seed=0, t=r.t, eta=r.eta, nu=r.nu, eta_hat=r.eta_hat,
                eta_ref=r.eta_ref, tau_cmd=r.tau_cmd, thrust=np.linspace(-1, 1, N * 8).reshape(N, 8),
                s=r.s, k1=r.k1, k2=r.k2, f_hat=r.f_hat, f_true=r.f_true, q=np.zeros((N, 4)), payload=r.payload,
                chat=r.chat, rmse=r.rmse, ok=True, t_fail=None, h=H,
                params_vector=np.tile([0.1, -0.5, 0.5], 8), meta={"param_names": names, "system": "eight"})
    assert plots.thruster_names(r8) == tuple(f"P{j}" for j in range(1, 9))
    fig = plots.plot_thrusts([r8])
    assert len(fig.axes) == 8 and [ax.get_title() for ax in fig.axes] == [f"P{j}" for j in range(1, 9)]
    assert sum(ax.get_xlabel() == "time (s)" for ax in fig.axes) == 2
    # its limits, per thruster: +-0.5 N reached at both ends of every panel
    assert all(len([ln for ln in ax.get_lines() if ln.get_label() == "saturation limit"]) == 2 for ax in fig.axes)
    assert plots.thruster_names(synthetic("agsta"))[0] == "T1 stern left"  # Haidou-1's six
