"""The text of a tiny tuning study, shared by the tests that run or parse one (and the hostile probe)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

TINY = """\
[study]
name = "{name}"
controllers = "{controller}"
seed = {seed}

[variables]
scale = {scale}

[algorithm]
name = "nsga2"
population = {population}
{algorithm_extra}
[termination]
max_generations = {generations}

[objectives]
names = ["chat", "rmse"]
reference_point = [300.0, 4.0]

[evaluation]
[[evaluation.draws]]
noise_seed = 0

[engine]
name = "local"
"""


def tiny_study(controller="agsta", seed=3, population=8, generations=3, scale=2.0, include_table2=None,
               name="tiny") -> str:
    extra = "" if include_table2 is None else f"include_table2 = {'true' if include_table2 else 'false'}\n"
    return TINY.format(controller=controller, seed=seed, population=population, generations=generations,
                       scale=scale, algorithm_extra=extra, name=name)


def small_study(name: str, controllers, *, seed: int, scale: float, population: int, generations: int,
                reference_point=(2.0, 2.0), include_table2: bool | None = None, objectives: tuple[str, ...] = (),
                system: str | None = None, scenario: str | None = None) -> str:
    """The TOML text of a small study on one draw (noise seed 1): ``controllers`` a law's name or a list of
    them, ``objectives`` extra lines of its [objectives] table, ``system`` and ``scenario`` its [evaluation]'s
    (a name, or a path relative to the study file), left out when None."""
    lines = ["[study]", f'name = "{name}"', f"controllers = {json.dumps(controllers)}", f"seed = {seed}",
             "[variables]", f"scale = {scale}", "[algorithm]", f"population = {population}"]
    if include_table2 is not None:
        lines.append(f"include_table2 = {'true' if include_table2 else 'false'}")
    lines += ["[termination]", f"max_generations = {generations}", "[objectives]", 'names = ["chat", "rmse"]',
              f"reference_point = {[float(v) for v in reference_point]}", *objectives, "[evaluation]"]
    lines += [f'{key} = "{value}"' for key, value in (("system", system), ("scenario", scenario)) if value is not None]
    lines += ["[[evaluation.draws]]", "noise_seed = 1"]
    return "\n".join(lines) + "\n"


def short_scenario(d: Path, system, duration: float) -> Path:
    """``d/short.toml``: the default scenario of ``system`` (a name or a system file) cut to ``duration`` s."""
    import arvcas
    from arvcas.sim import scenario

    s = arvcas.load_system(system)
    cfg = replace(scenario.load_scenario(s.params.default("scenario")), time_duration=duration)
    path = d / "short.toml"
    path.write_text(cfg.to_toml(), encoding="utf-8")
    return path
