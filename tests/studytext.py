"""The text of a tiny tuning study, shared by the tests that run or parse one."""

from __future__ import annotations

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
