"""The knees of a study's fronts, replayed: one traced run per controller, their result files, figures
and a table (``arvcas knees STUDY_DIR --out DIR``; STUDY_DIR holds one front or one per controller).

Each front's knee (pymoo's pseudo-weights, :func:`arvcas.tuning.front.knee_index`) is replayed with
its gains, the study's noise seed and scenario and the system the study ran on (the checkpoint names
it), so the replay's CHAT and RMSE are the front member's own, bit for bit (checked here). The table
adds the system's saturation envelope (:func:`arvcas.model.thrusters.envelope`) and each knee's
largest thrust, so a reader sees how much of the vehicle's capacity station keeping used.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from arvcas.controllers.gains import DOFS

__all__ = ["front_controllers", "replay_knees", "knees_markdown", "output_files"]


def front_controllers(study_dir: str | Path) -> list[str]:
    """The controller of each front of a study directory (:func:`arvcas.tuning.front.front_paths`; read from
    the files: a one-controller study's directory is named by the user)."""
    from arvcas.tuning import checkpoint as ck
    from arvcas.tuning.front import front_paths

    return [ck.read_checkpoint(f).controller for f in front_paths(study_dir)]


def output_files(out: str | Path, controllers, fmt: str = "png") -> list[Path]:
    out = Path(out)
    return ([out / f"knee_{c}.h5" for c in controllers] + [out / "knees.md"]
            + [out / f"knees_{n}.{fmt}" for n in ("states", "errors", "thrust")])


def replay_knees(study_dir: str | Path, out: str | Path, say=print, fmt: str = "png") -> dict:
    """Replay every front's knee; write ``knee_<controller>.h5``, ``knees.md`` and three figures (``fmt``:
    png, pdf or svg)."""
    from arvcas.util import files
    from arvcas.io import results, style
    from arvcas.io.plots import plot_errors, plot_states
    from arvcas.model import thrusters
    from arvcas.system.params import view
    from arvcas.sim.scenario import loads_scenario
    from arvcas.sim.simulation import simulate
    from arvcas.tuning import checkpoint as ck
    from arvcas.tuning.front import front_paths, member_gains, read_front, system_params

    out = Path(out)
    rows, runs = [], []
    system = None
    for path in front_paths(study_dir):
        fr = read_front(path)
        k = fr.knee()
        c = ck.read_checkpoint(path)
        params = system_params(c)
        system = params
        controller, gains, seed, cfg_text = member_gains(path, k)
        cfg = loads_scenario(cfg_text, f"{path} (study scenario)")
        r = simulate(controller, gains=gains, seed=seed, system=params, cfg=cfg)
        if not (np.array_equal(r.chat, fr.chat[0, k]) and np.array_equal(r.rmse, fr.rmse[0, k])):
            raise RuntimeError(f"{path}: the knee's replay does not reproduce its stored CHAT/RMSE "
                               f"(max difference {np.abs(r.chat - fr.chat[0, k]).max():.3g}); the model changed?")
        r.meta["front"], r.meta["front_index"] = str(path), int(k)
        dest = results.write_result(r, out / f"knee_{controller}.h5")
        say(f"{controller}: knee {k} of {fr.size}, F = ({', '.join(f'{x:.4g}' for x in fr.F[k])}); wrote {dest}")
        rows.append((controller, k, fr.size, fr.F[k], r))
        runs.append(r)
    lo, hi = thrusters.envelope(view(system))
    name = system.structure.name
    style.write_figure(out / f"knees_states.{fmt}",
                       plot_states(runs, title=f"Vehicle states at the fronts' knees ({name})"), fmt)
    style.write_figure(out / f"knees_errors.{fmt}",
                       plot_errors(runs, title=rf"State errors $e = \eta - y_1$ at the fronts' knees ({name})"), fmt)
    style.write_figure(out / f"knees_thrust.{fmt}", _thrust_figure(runs), fmt)
    files.write_text(out / "knees.md", _table(rows, system, lo, hi))
    return {c: r for c, *_, r in rows}


def knees_markdown(study_dir: str | Path, out: str | Path) -> str:
    """The text of ``knees.md`` rebuilt from the files ``replay_knees`` wrote (``knee_<controller>.h5`` in
    ``out``) and the study's fronts, without replaying: what checks a committed ``knees.md`` against its files."""
    from arvcas.io import results
    from arvcas.model import thrusters
    from arvcas.system.params import view
    from arvcas.tuning import checkpoint as ck
    from arvcas.tuning.front import front_paths, read_front, system_params

    rows, system = [], None
    for path in front_paths(study_dir):
        fr = read_front(path)
        k = fr.knee()
        system = system_params(ck.read_checkpoint(path))
        r = results.read_result(Path(out) / f"knee_{fr.controller}.h5")
        rows.append((fr.controller, k, fr.size, fr.F[k], r))
    lo, hi = thrusters.envelope(view(system))
    return _table(rows, system, lo, hi)


def _thrust_figure(runs):
    """Thrust of every thruster (one panel per run: the vehicle may have any number of thrusters), named
    as the system names them."""
    from arvcas.io import style
    from arvcas.io.plots import controller_label, thruster_names

    @style.styled
    def draw():
        fig = style.figure("page", 1.9 * len(runs) + 0.5)
        axes = fig.subplots(len(runs), 1, sharex=True, squeeze=False)[:, 0]
        for ax, r in zip(axes, runs):
            u = np.asarray(r.thrust)
            for j, name in enumerate(thruster_names(r)):
                style.trace(ax, r.t, u[:, j], color=style.color("", j), label=name)
            ax.set_title(controller_label(r.controller))
            ax.set_ylabel("thrust (N)")
            ax.grid(True, alpha=0.5)
            ax.margins(x=0)
            ax.legend(ncol=min(8, u.shape[1]), loc="upper right", fontsize=6)
        axes[-1].set_xlabel("time (s)")
        fig.suptitle("Thrust per thruster at each front's knee")
        return fig

    return draw()


def _table(rows, params, lo, hi) -> str:
    name = params.structure.name
    L = [f"# Knees of the fronts: {name}", "",
         "Each front's knee (pymoo pseudo-weights 0.5/0.5) replayed with its gains, the study's noise seed and "
         "scenario; the replay reproduces the member's stored CHAT and RMSE bit for bit.", "",
         "| controller | knee | f_chat | f_rmse | " + " | ".join(f"CHAT {d}" for d in DOFS) + " | "
         + " | ".join(f"RMSE {d}" for d in DOFS) + " | max thrust N |",
         "|---|---|---|---|" + "---|" * 12 + "---|"]
    for controller, k, n, F, r in rows:
        L.append(f"| {controller} | {k} of {n} | {F[0]:.4g} | {F[1]:.4g} | "
                 + " | ".join(f"{x:.4g}" for x in r.chat) + " | " + " | ".join(f"{x:.4g}" for x in r.rmse)
                 + f" | {np.abs(r.thrust).max():.3g} |")
    L += ["", "CHAT in N (x, y, z) and N m (phi, theta, psi) per sample; RMSE in m and rad.", "",
          f"Saturation envelope of {name} (pure-axis capacity of the allocation within every thruster's limits, "
          "`arvcas.model.thrusters.envelope`):", "",
          "| | " + " | ".join(DOFS) + " |", "|---|" + "---|" * 6,
          "| negative | " + " | ".join(f"{-x:.4g}" for x in lo) + " |",
          "| positive | " + " | ".join(f"{x:.4g}" for x in hi) + " |", "",
          "N for x, y, z; N m for phi, theta, psi."]
    return "\n".join(L) + "\n"
