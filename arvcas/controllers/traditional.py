"""The proposed controller with the "traditional" decreasing law that zigzags around k1min (Fig. 10)."""

from __future__ import annotations

from arvcas.controllers import gsta
from arvcas.controllers.base import register
from arvcas.controllers.proposed import Proposed

__all__ = ["Traditional"]


class Traditional(Proposed):
    name = "traditional"  # the paper's name (files, directories and compiled functions keep it)
    aliases = ("agsta_reso_updown",)  # what it is: AGSTA, RESO, the gain stepping up and down by l (the zigzag)
    label = "Traditional law"
    color = "tab:orange"
    description = "the proposed controller with the traditional decreasing law of Fig. 10"

    def k1_next(self, G, k1, s, h):
        return gsta.k1_next_traditional(k1, s, G["sigma"], G["l"], G["k1min"], h)


register(Traditional())
