"""Fronts you can explore: one self-contained HTML page (``arvcas front explore DIR --out front.html``).

The page holds every front of the given studies in one plot, each controller in its colour, its knee
(diamond: :meth:`arvcas.tuning.front.Front.knee`, pseudo-weights closest to 1/m for m objectives) and its
default gains on the same draw (star, where they did not diverge; Haidou-1: Table 2). The plot's axes are
the studies' objectives (docs/objectives.md): the paper's two, f_chat against f_rmse, as before; two other
objectives, those two; three or four, two at a time, chosen by a selector for each axis above the plot
(default the first two; ``#x=NAME&y=NAME`` in the page's address opens another pair), the others in the
hover and the details. An axis is titled as ``front plot`` names the objective (``f_<name>``, with its
unit from the objective registry; f_chat and f_rmse: "mean CHAT, normalised") and is logarithmic only
where every value drawn on it (members, feasible population, default gains, of every front) is
positive. Fronts of different systems or of different objectives are refused (one line naming both).
Hovering a member shows all its objectives, per-DOF CHAT and RMSE and its gains; clicking it
shows its time response: the tracking error e = eta - y1 of the six DOF (one line per selected
member, so members can be compared) and the thrust of every thruster of the last one selected, with
its gains, metrics and the command that replays it (``arvcas simulate --from-front ... --index I``).

Time responses are computed once, when the page is written: each member is replayed with its gains,
the study's scenario, system and first draw (noise seed, nominal-model factors, phases) by the
compiled run (:meth:`arvcas.sim.run.CompiledRun.simulate`, the path ``arvcas simulate --from-front``
takes), and for a one-draw study the replay's per-DOF CHAT and RMSE are checked to equal the stored
ones bit for bit (else the page is refused, or with ``allow_model_change`` it says by how much they
differ). ``members``: every member (``"all"``), only the knee, or N members spread evenly along the
front plus the knee; the others can still be hovered. Each trace keeps ``samples`` samples (every
k-th controller sample, the first and the last kept), each series quantised to 16 bits over its own
range (an error of at most 1/131,068 of that range) and stored as base64.

The page needs no server and no network: plotly.js (from the ``plotly`` Python package, the optional
``explore`` extra) is inlined, about 4.8 MB of the page; the data and the page's own script follow it.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import numpy as np

from arvcas.system import DEFAULT

__all__ = ["page_data", "page_html", "write_page", "member_selection", "explore_fronts", "DEFAULT_SAMPLES",
           "FORMAT", "FORMAT_VERSION"]

FORMAT = "arvcas-front-explorer"
FORMAT_VERSION = 2  # 2: "objectives" (the columns of F, the axes), F of 2-4 objectives
DEFAULT_SAMPLES = 300
_TEMPLATES = Path(__file__).resolve().parent / "templates"
_NAN = 65535  # the quantised code of a missing (non-finite) sample


def explore_fronts(paths) -> list[Path]:
    """The ``front.h5`` files of the given study directories or front files, in order, each once."""
    from arvcas.tuning.front import front_paths

    out: list[Path] = []
    for p in paths:
        for f in front_paths(p):
            if f.resolve() not in [o.resolve() for o in out]:
                out.append(f)
    return out


def member_selection(size: int, knee: int, members) -> list[int]:
    """The members whose time response the page stores: ``"all"``, ``"knee"``, or an integer N: N members
    spread evenly along the front (both ends included) and the knee."""
    if members == "all":
        return list(range(size))
    if members == "knee":
        return [knee] if size else []
    n = int(members)
    if n < 1:
        raise ValueError(f"--members: expected all, knee or a count >= 1, got {members!r}")
    pick = set(np.unique(np.round(np.linspace(0, size - 1, min(n, size))).astype(int)).tolist()) if size else set()
    return sorted(pick | ({knee} if size else set()))


def _pack(a: np.ndarray) -> dict:
    """A (samples, width) array as 16-bit codes per column: value = lo + step * code; code 65535: missing."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    fin = np.isfinite(a)
    masked = np.where(fin, a, np.nan)
    with np.errstate(all="ignore"):
        lo = np.where(fin.any(axis=0), np.nanmin(masked, axis=0), 0.0)
        hi = np.where(fin.any(axis=0), np.nanmax(masked, axis=0), 0.0)
    step = np.where(hi > lo, (hi - lo) / (_NAN - 1), 1.0)
    q = np.clip(np.round((np.where(fin, a, lo) - lo) / step), 0, _NAN - 1).astype("<u2")
    q[~fin] = _NAN
    return {"lo": [float(x) for x in lo], "step": [float(x) for x in step],
            "q": base64.b64encode(q.tobytes()).decode("ascii")}


def _rounded(x, digits: int = 6):
    """Floats with ``digits`` significant digits for display (None for NaN and inf)."""
    arr = np.asarray(x, dtype=float)
    out = [float(f"{v:.{digits}g}") if np.isfinite(v) else None for v in arr.ravel()]
    return out if arr.ndim <= 1 else [out[i:i + arr.shape[-1]] for i in range(0, len(out), arr.shape[-1])]


def _keep(n: int, samples: int) -> np.ndarray:
    """Indices of ``samples`` of ``n`` samples: every k-th, the first and the last included."""
    if n <= samples:
        return np.arange(n)
    k = int(np.ceil((n - 1) / (samples - 1)))
    idx = np.arange(0, n, k)
    return idx if idx[-1] == n - 1 else np.append(idx, n - 1)


def _objectives(names, fronts, norm: str) -> list[dict]:
    """The page's objectives, the columns of every front's F: name, axis title, unit, description, and
    whether the axis is logarithmic (every value the page draws on it, members, population and default
    gains, positive). CHAT and RMSE keep the paper-style titles; another objective is titled as ``front
    plot`` names it (``f_<name>``) with its unit from the objective registry (none if it is not loaded)."""
    from arvcas.metrics import objectives as objectives_mod

    out = []
    for j, n in enumerate(names):
        if n in ("chat", "rmse"):
            unit, label = "1", f"f_{n} (mean {n.upper()}, normalised)"
            desc = f"mean over the six DOF of {n.upper()}, divided by {norm}"
        else:
            try:
                o = objectives_mod.get(n)
                unit, desc = o.unit, o.description
            except (objectives_mod.ObjectiveError, ValueError):
                unit, desc = "", ""
            label = f"f_{n} ({unit})" if unit else f"f_{n}"
        vals = [v for f in fronts for v in [*(p[j] for p in f["F"]), *(p[j] for p in f["population"]),
                                             f["defaults"]["F"][j]] if v is not None]
        out.append({"name": n, "label": label, "unit": unit, "description": desc,
                    "log": bool(vals) and all(v > 0 for v in vals)})
    return out


def _checked(path: Path, allow_model_change: bool):
    """A front, its checkpoint, system, scenario, what changed since the study (checked before any run) and
    whether the page may be written when a replay does not reproduce (``allow_model_change``)."""
    from arvcas.sim.scenario import loads_scenario
    from arvcas.tuning import checkpoint as ck
    from arvcas.tuning.front import check_provenance, read_front, system_params

    fr = read_front(path)
    c = ck.read_checkpoint(fr.path)
    params = system_params(c)
    changed = check_provenance(fr.path, params, allow_model_change, "front explore")
    cfg = loads_scenario(fr.scenario_text, f"{fr.path} (study scenario)")
    return fr, c, params, cfg, changed, allow_model_change


def _front_data(path: Path, checked, members, samples: int, say) -> dict:
    from arvcas.io.plots import controller_color, controller_label, thruster_names
    from arvcas.sim.simulation import compiled_run

    fr, c, params, cfg, changed, allow = checked
    run = compiled_run(fr.controller, params, cfg)
    seed, unc, phase = int(fr.draw_seeds[0]), fr.draw_uncertainty[0], fr.draw_phase[0]
    one_draw = fr.draw_seeds.size == 1
    knee = fr.knee() if fr.size else -1
    chosen = member_selection(fr.size, knee, members)
    traces: dict[str, dict] = {}
    keep = t = names = None
    worst = 0.0

    def replay(key: str, gains, chat_ref, rmse_ref):
        nonlocal keep, worst, names, t
        r = run.simulate(gains, seed, unc, phase)
        if one_draw and chat_ref is not None and np.all(np.isfinite(chat_ref)):
            d = max(float(np.max(np.abs(r.chat - chat_ref))), float(np.max(np.abs(r.rmse - rmse_ref))))
            if d != 0.0 and not (changed or allow):  # allowed: the page records the difference
                raise ValueError(f"front explore: {fr.path}: member {key}'s replay does not reproduce its stored CHAT/RMSE "
                                 f"(max difference {d:.3g}); the model changed? (--allow-model-change to write the "
                                 f"page anyway; it records the difference)")
            worst = max(worst, d)
        if keep is None:
            keep = _keep(len(r.t), samples)
            names, t = list(thruster_names(r)), np.asarray(r.t)[keep]
        traces[key] = {"e": _pack((r.eta - r.eta_ref)[keep]), "u": _pack(np.asarray(r.thrust)[keep]),
                       "ok": bool(r.ok), "t_fail": None if r.ok else float(r.t_fail)}

    say(f"{fr.controller}: replaying {len(chosen)} of {fr.size} members and the default gains ({fr.path}) ...")
    for i in chosen:
        replay(str(i), fr.gains[i], fr.chat[0, i], fr.rmse[0, i])
    replay("defaults", fr.table2, c.table2_chat[0] if c.table2_chat is not None else None,
           c.table2_rmse[0] if c.table2_rmse is not None else None)
    m = len(fr.objectives)  # Table 2's objectives: one per objective, NaN where it diverged or was not evaluated
    defaults_F = fr.table2_F if fr.table2_F.size == m else np.full(m, np.nan)
    feas = (fr.population_G <= 0).all(axis=1) & np.isfinite(fr.population_F).all(axis=1)  # as the front's members
    return {
        "path": str(path), "controller": fr.controller, "label": controller_label(fr.controller),
        "color": controller_color(fr.controller), "study": fr.study_name, "status": fr.status, "n_gen": fr.n_gen,
        "n_eval": fr.n_eval, "hv": fr.hv, "reference_point": fr.reference_point.tolist(), "knee": knee,
        "system": fr.system or DEFAULT, "draws": int(fr.draw_seeds.size), "seed": seed,
        "gain_names": list(fr.names), "F": fr.F.tolist(), "gains": _rounded(fr.gains),
        "chat": _rounded(fr.chat.mean(axis=0)), "rmse": _rounded(fr.rmse.mean(axis=0)),
        "population": fr.population_F[feas].tolist(),
        "defaults": {"F": [None if not np.isfinite(x) else float(x) for x in defaults_F], "gains": _rounded(fr.table2),
                     "chat": _rounded(c.table2_chat.mean(axis=0)) if c.table2_chat is not None else None,
                     "rmse": _rounded(c.table2_rmse.mean(axis=0)) if c.table2_rmse is not None else None},
        "t": _rounded(t, 9), "k": int(keep[1] - keep[0]) if keep.size > 1 else 1, "h": cfg.time_h,
        "thrusters": names, "traces": traces,
        "replay": {"reproduced": one_draw and worst == 0.0, "max_difference": worst, "model_change": changed},
    }


def page_data(paths, members="all", samples: int = DEFAULT_SAMPLES, allow_model_change: bool = False,
              say=None) -> dict:
    """Everything the page shows, as JSON-ready data (module docstring)."""
    from arvcas._version import __version__
    from arvcas.controllers.gains import DOFS
    from arvcas.metrics.indices import defaults_name, norm_name

    say = say or (lambda msg: None)
    if samples < 2:
        raise ValueError(f"--samples: expected at least 2, got {samples}")
    if members not in ("all", "knee"):
        member_selection(1, 0, members)  # a bad count is refused before any run
    paths = explore_fronts(paths)
    checked = [_checked(p, allow_model_change) for p in paths]
    sets = {}  # objective set -> the first front that has it
    for ch in checked:
        sets.setdefault(ch[0].objectives, ch[0].path)
    if len(sets) > 1:
        raise ValueError("front explore: the fronts have different objectives (" + "; ".join(
            f"{', '.join(o)} in {p}" for o, p in sets.items()) + "); one page shows fronts of one set of objectives")
    systems = sorted({ch[0].system for ch in checked})  # as fronts record it: "" is the default system
    if len(systems) > 1:
        raise ValueError(f"front explore: the fronts are of different systems ({', '.join(s or DEFAULT for s in systems)}); their objectives "
                         "are normalised differently and cannot share one plot")
    recorded_system = systems[0]
    system = recorded_system or DEFAULT
    fronts = [_front_data(p, ch, members, samples, say) for p, ch in zip(paths, checked)]
    recorded = sorted({ch[1].normalisation for ch in checked if ch[1].normalisation})  # fronts since it is recorded
    if len(recorded) > 1:
        raise ValueError(f"front explore: the fronts' objectives are normalised differently ({'; '.join(recorded)}) "
                         f"and cannot share one plot")
    norm = recorded[0] if recorded else norm_name(recorded_system)
    objectives = _objectives(checked[0][0].objectives, fronts, norm)
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION, "arvcas_version": __version__, "system": system,
        "title": f"Fronts of {', '.join(dict.fromkeys(f['study'] for f in fronts))} ({system})",
        "normalisation": norm, "defaults_name": defaults_name(recorded_system),
        "dofs": list(DOFS), "dof_units": ["m", "m", "m", "rad", "rad", "rad"], "objectives": objectives,
        "fronts": fronts,
    }


def inline_json(doc) -> str:
    """``doc`` as JSON safe inside an HTML ``<script>`` block: every ``<``, ``>`` and ``&`` written as its
    ``\\u`` escape, so no name (``</script``, ``<!--``, ``<script``) changes how the browser parses the page;
    ``JSON.parse`` reads the same strings back."""
    text = json.dumps(doc, separators=(",", ":"), allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def page_html(doc: dict) -> str:
    """The page: plotly.js, the data and the page's script inlined (no server, no network)."""
    try:
        from plotly.offline import get_plotlyjs
    except ImportError:
        raise ValueError("front explore: needs the plotly package (pip install 'arvcas[explore]')") from None
    data = inline_json(doc)
    page = (_TEMPLATES / "explore.html").read_text(encoding="utf-8")
    script = (_TEMPLATES / "explore.js").read_text(encoding="utf-8")
    parts = {"TITLE": html.escape(doc["title"]), "PLOTLY": get_plotlyjs(), "DATA": data, "SCRIPT": script}
    head, *rest = page.split("@@")
    out = [head]
    for i, piece in enumerate(rest):
        out.append(parts[piece] if i % 2 == 0 else piece)
    return "".join(out)


def write_page(paths, out, members="all", samples: int = DEFAULT_SAMPLES, allow_model_change: bool = False,
               say=None) -> Path:
    """Write the page of the fronts in ``paths`` (study directories or front files) to ``out`` (atomic)."""
    from arvcas.experiments import _io

    text = page_html(page_data(paths, members, samples, allow_model_change, say))
    return _io.write_text(Path(out), text)
