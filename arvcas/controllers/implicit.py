"""The proposed controller with the implicit GSTA step (the paper's future work, docs/model.md §5b)."""

from __future__ import annotations

from arvcas.controllers.base import register
from arvcas.controllers.proposed import Proposed

__all__ = ["Implicit"]


class Implicit(Proposed):
    name = "implicit"
    description = "the proposed controller with the implicit GSTA step (docs/model.md §5b)"
    implicit = True


register(Implicit())
