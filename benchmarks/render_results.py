"""Re-render the results' generated text from their committed data: nothing measured is touched.

Each generated page of ``results/`` is written by the script that measured it, from the JSON it saved beside
it, or by a script kept in its folder from that folder's committed result files (``results/ardusub/render.py``,
``results/bluerov2/side_by_side.py``); this script renders every such page again from those files alone, so that editing a page's wording (in the
script) and checking that the committed page is the script's rendering of the committed data need no
re-measurement. A page may keep a note (what changed since its study ran) in a template beside it, ``X.note.in``,
rendered by benchmarks/readme.py's placeholders and appended. ``python benchmarks/readme.py --check`` runs this
check too:

    python benchmarks/render_results.py           # rewrite the pages below
    python benchmarks/render_results.py --check   # exit 1 naming each page that differs (tests/test_readme.py)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # the benchmarks package is the checkout's; appended, so an installed arvcas
    sys.path.append(str(ROOT))  # stays the one imported (CI runs the suite against the wheel)


def _bench_md(doc: dict) -> str:
    from arvcas.bench.report import render_markdown
    return render_markdown(doc)


def _cost_readme(doc: dict) -> str:
    from arvcas.bench import cost
    return cost.readme(doc["cost"])


def _bluerov2_step(doc: dict) -> str:
    from benchmarks import bluerov2_step
    return bluerov2_step.markdown(doc)


def _sample_cost(doc: dict) -> str:
    from benchmarks import sample_cost
    return sample_cost.markdown(doc)


def _thrusters(doc: dict) -> str:
    from benchmarks import thruster_step
    return thruster_step.markdown(doc)


def _lockstep(doc: dict) -> str:
    from benchmarks import lockstep
    return lockstep.markdown(doc)


def _step_accuracy(doc: dict) -> str:
    from benchmarks import step_accuracy
    return step_accuracy.markdown(doc)


def _validation(_doc) -> str:
    from benchmarks import validation
    return validation.summary_markdown(ROOT / "results" / "validation")


def _synthetic(doc: dict) -> str:
    from benchmarks import validation
    return validation.synthetic_markdown(doc)


def _intervals(_doc) -> str:
    from benchmarks import intervals
    return intervals.readme_markdown(ROOT / "results" / "validation" / "intervals")


def _report(module: str, reader: str, markdown: str, *paths: str):
    """The report arvcas wrote beside its result file(s): ``module.markdown(module.reader(path), ...)``."""
    def fn(_doc) -> str:
        import importlib
        mod = importlib.import_module(module)
        return getattr(mod, markdown)(*(getattr(mod, reader)(ROOT / p) for p in paths))
    return fn


_MC = ("arvcas.experiments.montecarlo", "read_montecarlo")


def _knees(study: str):
    """``knees.md`` of ``arvcas knees STUDY --out STUDY/knees``, from the knee files and the fronts."""
    def fn(_doc) -> str:
        from arvcas.experiments.knees import knees_markdown
        return knees_markdown(ROOT / study, ROOT / study / "knees")
    return fn


def _table3(_doc) -> str:
    """results/paper/table3.md from the three runs; its time stamp is the last run's (when arvcas paper wrote
    the table)."""
    import h5py

    from arvcas.experiments.paper import CONTROLLERS, table3_from_results
    out = ROOT / "results" / "paper"
    created = []
    for c in CONTROLLERS:
        with h5py.File(out / f"{c}.h5", "r") as h:
            created.append(str(h.attrs["created"]))
    return table3_from_results(out, created=max(created))


def _folder_script(path: str):
    """A page written by a script kept in its results folder, from that folder's committed files."""
    def fn(_doc) -> str:
        import importlib.util
        spec = importlib.util.spec_from_file_location("arvcas_results_" + Path(path).parent.name, ROOT / path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod.markdown()
    return fn


def _note(template: str, root: Path = ROOT) -> str:
    """The text of a note kept beside a generated page (what happened since its study ran), rendered from its
    template by benchmarks/readme.py: every number in it from a committed file."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("arvcas_readme_renderer", ROOT / "benchmarks" / "readme.py")
    readme = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(readme)
    return readme.body((root / template).read_text(), root)


# (the page, the JSON it is rendered from, the renderer[, a note's template appended to it]), paths relative to
# the checkout
PAGES = [
    ("results/bench.md", "results/bench.json", _bench_md),
    ("results/cost/README.md", "results/bench.json", _cost_readme),
    ("results/bluerov2_step/README.md", "results/bluerov2_step/bluerov2_step.json", _bluerov2_step),
    ("results/bluerov2_step/sample_cost.md", "results/bluerov2_step/sample_cost.json", _sample_cost),
    ("results/step/bluerov2_heavy_alpha5/thrusters.md", "results/step/bluerov2_heavy_alpha5/thrusters.json", _thrusters),
    ("results/lockstep/README.md", "results/lockstep/lockstep.json", _lockstep),
    ("results/step/README.md", "results/step/step_accuracy.json", _step_accuracy, "results/step/README.note.in"),
    ("results/step/bluerov2_heavy_alpha5/README.md", "results/step/bluerov2_heavy_alpha5/step_accuracy.json",
     _step_accuracy, "results/step/bluerov2_heavy_alpha5/README.note.in"),
    # scripts in their folder, reading that folder's committed fronts (no JSON: the renderer reads them)
    ("results/ardusub/README.md", None, _folder_script("results/ardusub/render.py")),
    ("results/ardusub/identified/README.md", None, _folder_script("results/ardusub/identified/render.py")),
    ("results/bluerov2/side_by_side.md", None, _folder_script("results/bluerov2/side_by_side.py")),
    # benchmarks/validation.py's summary, from the JSON files and identify.log of results/validation
    ("results/validation/README.md", None, _validation),
    ("results/validation/intervals/README.md", None, _intervals),
    ("results/validation/synthetic/README.md", "results/validation/synthetic/synthetic.json", _synthetic),
    # the reports arvcas wrote beside its result files (results/beyond/run.sh, arvcas paper), from those files
    ("results/paper/table3.md", None, _table3),
    *((f"{d}/knees/knees.md", None, _knees(d)) for d in ("results/bluerov2", "results/bluerov2/t200",
                                                         "results/bluerov2/t200_group_noise",
                                                         "results/bluerov2_tracking")),
    # (not the robust fronts' pages: their pairwise dominance tests take minutes to re-render)
    *((f"results/beyond/{d}/{c}.md", None, _report(*_MC, "summary_markdown", f"results/beyond/{d}/{c}.h5"))
      for d, cs in (("mc", ("proposed", "agsta", "traditional", "implicit")), ("knee", ("proposed", "agsta")))
      for c in cs),
    *((f"results/beyond/{name}.md", None,
       _report(*_MC, "compare_markdown", f"results/beyond/{a}.h5", f"results/beyond/{b}.h5"))
      for name, a, b in (("mc/proposed_vs_agsta", "mc/proposed", "mc/agsta"),
                         ("mc/implicit_vs_proposed", "mc/implicit", "mc/proposed"),
                         ("mc/traditional_vs_proposed", "mc/traditional", "mc/proposed"),
                         ("knee/proposed_vs_agsta", "knee/proposed", "knee/agsta"),
                         ("knee/proposed_knee_vs_table2", "knee/proposed", "mc/proposed"),
                         ("knee/agsta_knee_vs_table2", "knee/agsta", "mc/agsta"))),
    *((f"results/beyond/{d}/sweep.md", None,
       _report("arvcas.experiments.sweep", "read_sweep", "sweep_markdown", f"results/beyond/{d}/sweep.h5"))
      for d in ("sweep", "sweep_noisefree")),
]


def rendered(root: Path = ROOT) -> dict[str, str]:
    """Every page's text as its script renders it from the committed JSON (and its note, if it has one)."""
    return {page: fn(json.loads((root / src).read_text()) if src else None)
            + "".join("\n" + _note(n, root) for n in note) for page, src, fn, *note in PAGES}


def _write(path: Path, text: str) -> None:
    """A page arvcas's writer recorded in its folder's manifest is replaced through that writer (the manifest
    stays true); the others were written plainly by their scripts and are so again."""
    from arvcas.util import files
    if files.written_by_arvcas(path):
        files.write_text(path, text, kind="md")
    else:
        path.write_text(text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="re-render the results' generated pages from their committed JSON")
    ap.add_argument("--check", action="store_true", help="exit 1 if a committed page differs from its rendering")
    a = ap.parse_args(argv)
    stale = []
    for page, text in rendered().items():
        if a.check:
            if (ROOT / page).read_text() != text:
                stale.append(page)
        elif (ROOT / page).read_text() != text:  # an unchanged page (and its folder's manifest) is left alone
            _write(ROOT / page, text)
    if stale:
        print("render_results: differ from their rendering (run python benchmarks/render_results.py): "
              + ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
